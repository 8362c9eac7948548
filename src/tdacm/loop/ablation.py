"""Ablation of the state estimate: the low-level controller reads chosen coordinates from the
plant instead of the estimator (scenario key ``estimation.controller_truth``).

Why: to measure what each part of the estimation error costs the closed loop. One example is
"how well would test C do on estimates if the drone's horizontal velocity were measured
exactly?". The answer bounds what a better sensor or filter for that quantity could gain
(docs/estimation.md, "What limits test C"). This is a diagnostic, not a robot: it breaks the rule that
nothing downstream of the sensors reads the plant. So it is off by default, allowed only with
``estimation.source = "estimated"``, and named in ``summary.json`` (``controller_truth``). The
servo, the virtual camera and the estimator itself are unchanged; they still see estimates
only.

The key is a comma-separated list of slices of ``q`` and ``qd`` in Python notation, for
example ``"qd[3:5]"`` (horizontal drone velocity), ``"q[0:2],qd[0:2]"`` (roll and pitch with
their rates), or ``"q[0:6],qd[0:6]"`` (the whole drone state). ``""`` means none.
"""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np

from .data import ActuatorCommand, ServoCommand, StateEstimate

_ITEM = re.compile(r"^(q|qd)\[(\d+)(?::(\d+))?\]$")


def parse_controller_truth(text: str, n: int | None = None) -> tuple[list[int], list[int]]:
    """``(q indices, qd indices)`` of ``text`` (module docstring), sorted and unique. With
    ``n``, the indices are checked against the number of coordinates. ``ValueError`` naming
    the key on bad syntax, an empty slice or an index out of range."""
    idx = {"q": set(), "qd": set()}
    if not isinstance(text, str):
        raise ValueError(f"estimation.controller_truth must be a string, got {text!r}")
    for raw in text.split(",") if text.strip() else []:
        item = raw.strip().replace(" ", "")
        m = _ITEM.match(item)
        if m is None:
            raise ValueError(
                f"estimation.controller_truth: {raw.strip()!r} is not q[i], q[i:j], qd[i] or "
                "qd[i:j] (comma-separated, e.g. 'qd[3:5]' or 'q[0:6],qd[0:6]')"
            )
        name, a = m.group(1), int(m.group(2))
        b = int(m.group(3)) if m.group(3) is not None else a + 1
        if b <= a:
            raise ValueError(f"estimation.controller_truth: {item} is an empty slice")
        if n is not None and b > n:
            raise ValueError(
                f"estimation.controller_truth: {item} reaches past the robot's {n} coordinates"
            )
        idx[name].update(range(a, b))
    return sorted(idx["q"]), sorted(idx["qd"])


class TruthAblation:
    """A low-level controller block that hands its wrapped ``controller`` the estimate with
    the coordinates ``q_idx`` / ``qd_idx`` replaced by the plant's (module docstring)."""

    def __init__(self, controller, plant, q_idx, qd_idx):
        self.controller = controller
        self.plant = plant
        self.q_idx = np.asarray(q_idx, dtype=np.int64)
        self.qd_idx = np.asarray(qd_idx, dtype=np.int64)

    def _patched(self, estimate: StateEstimate) -> StateEstimate:
        s = self.plant.state
        q, qd = estimate.q.copy(), estimate.qd.copy()
        q[self.q_idx] = s.q[self.q_idx]
        qd[self.qd_idx] = s.qd[self.qd_idx]
        return replace(estimate, q=q, qd=qd)

    def reset(self, estimate: StateEstimate) -> None:
        self.controller.reset(self._patched(estimate))

    def step(self, estimate: StateEstimate, command: ServoCommand, dt: float) -> ActuatorCommand:
        return self.controller.step(self._patched(estimate), command, dt)
