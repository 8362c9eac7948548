"""The state estimate every block downstream of the sensors reads (a module of its own, with no
dependencies, so that the estimator and the loop share one record without importing each
other)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StateEstimate:
    """``q_hat``, ``qdot_hat`` at time ``t`` and, from an estimator, the covariance ``P`` of
    ``[q, qd]`` (``2n x 2n``; ``None`` for the true state). ``failure``: why the estimator
    cannot go on (it diverged); the closed loop then ends the run."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    P: np.ndarray | None = None
    failure: str | None = None
