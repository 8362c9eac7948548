"""Validation of an identified model on a held-out experiment (not used by the fit)."""

from __future__ import annotations

import numpy as np

from .experiments import synthesize


def held_out_rms(values: dict, seed: int = 0, truth: dict | None = None) -> float:
    """RMS (m) of the tip position predicted by the model with ``values`` against the
    recorded (noisy) tip of the ``held-out`` experiment (5 s from rest, tension sines over a
    ramp): one simulation from the known rest state with the recorded (noisy) tensions, no
    re-initialization."""
    rec = synthesize("held-out", seed=seed, truth=truth)
    n = rec.model.system.n
    pred = rec.model.simulate(values, np.zeros((1, n)), np.zeros((1, n)), [0], [len(rec.t)],
                              rec.u, rec.dt)  # fmt: skip
    e = pred.tip[:, :3, 3] - rec.tip[:, :3, 3]
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))
