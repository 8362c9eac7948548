"""The low-level control block (paper, "Model-Based Control"): the adaptive sliding-mode law,
the hierarchical drone loop and the thrust/tension allocation of
:class:`~tdacm.control.TDACMController`, behind the :class:`~.protocols.LowLevelController`
protocol (or with the PD + gravity law of :mod:`tdacm.control.pd` in its place); and the loader
of user controllers named in a scenario."""

from __future__ import annotations

import importlib
import sys

from ..control import TDACMController
from ..control.config import ControlLawConfig
from ..control.hierarchical import LAW_ADAPTIVE, LAW_PD
from .data import ActuatorCommand, ServoCommand, StateEstimate
from .protocols import ControllerContext, LowLevelController


class AdaptiveLowLevel:
    """The paper's controller (eqs. S2-S10) with the drone loop and allocation."""

    #: The law of the compiled step (:data:`~tdacm.control.hierarchical.LAW_ADAPTIVE` or
    #: :data:`~tdacm.control.hierarchical.LAW_PD`).
    law_kind = LAW_ADAPTIVE

    def __init__(self, context: ControllerContext):
        law = context.law
        if law is None:  # a context made by hand: the law's keys among its options
            o = context.options
            law = ControlLawConfig(**{k: o[k] for k in ControlLawConfig.model_fields if k in o})
        self.controller = TDACMController.from_config(
            context.system, context.model, context.q_star, law, kind=self.law_kind
        )

    def reset(self, estimate: StateEstimate) -> None:
        self.controller.reset()

    def step(self, estimate: StateEstimate, command: ServoCommand, dt: float) -> ActuatorCommand:
        cs = self.controller.step(
            estimate.q, estimate.qd, command.q_d, command.qd_d, command.qdd_d, dt
        )
        return ActuatorCommand(
            cs.u, cs.tau, cs.q_ref, cs.V, cs.delta_hat, cs.thrust_saturated, cs.tension_saturated
        )


class PDGravityController(AdaptiveLowLevel):
    """PD + gravity (:mod:`tdacm.control.pd`) with the same drone loop and
    allocation: ``controller.class = "tdacm.loop.lowlevel:PDGravityController"``."""

    law_kind = LAW_PD


def load_class(path: str, search: tuple[str, ...] = ()):
    """``"package.module:ClassName"`` -> the class (``ValueError`` naming the path if absent).

    The module is imported from ``sys.path``, then from the folders of ``search`` (the
    current folder and the scenario file's folder, see :func:`tdacm.loop.build.build_loop`),
    so ``mylab/pid.py`` next to where ``tdacm run`` is called is found as ``mylab.pid``, as
    ``python -m`` would find it; entries of ``sys.path`` come first, so nothing installed is
    shadowed."""
    mod_name, sep, cls_name = path.partition(":")
    if not sep or not mod_name or not cls_name:
        raise ValueError(f"controller.class must read 'package.module:ClassName', got {path!r}")
    extra = [p for p in dict.fromkeys(search) if p and p not in sys.path]
    sys.path.extend(extra)
    try:
        module = importlib.import_module(mod_name)
    except ImportError as exc:
        raise ValueError(f"controller.class {path!r}: cannot import {mod_name!r} ({exc})") from None
    finally:
        for p in extra:
            sys.path.remove(p)
    cls = getattr(module, cls_name, None)
    if cls is None:
        raise ValueError(f"controller.class {path!r}: {mod_name} has no {cls_name!r}")
    return cls


def make_low_level(
    path: str | None, context: ControllerContext, search: tuple[str, ...] = ()
) -> LowLevelController:
    """The scenario's controller: the adaptive one, or ``path`` built as ``cls(context)``
    (``search``: folders where its module is looked for after ``sys.path``)."""
    if not path:
        return AdaptiveLowLevel(context)
    try:
        ctl = load_class(path, search)(context)
    except ValueError:
        raise
    except Exception as exc:  # a user's constructor: report it under the scenario key
        raise ValueError(
            f"controller.class {path!r}: building it from a ControllerContext failed: "
            f"{type(exc).__name__}: {exc}"
        ) from None
    if not isinstance(ctl, LowLevelController):
        raise ValueError(
            f"controller.class {path!r} does not implement reset(estimate) and "
            "step(estimate, command, dt) (see tdacm.loop.protocols.LowLevelController)"
        )
    return ctl
