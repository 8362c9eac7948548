"""Baseline models to compare the GVS model against.

* :class:`CCLagrangian`: the constant-curvature coupled Lagrangian model of the paper's
  comparison (energies written with sympy, equations of motion by symbolic differentiation,
  generated code cached on disk); same ``terms`` / ``forward_dynamics`` interface as
  :class:`tdacm.TDACM`.
"""

from .cc import CCLagrangian, cc_paper_system
from .codegen import cache_dir, generated_module
from .derivation import DerivationSpec, derive
from .integrate import rk4_simulate, rk4_step

__all__ = [
    "CCLagrangian",
    "DerivationSpec",
    "cache_dir",
    "cc_paper_system",
    "derive",
    "generated_module",
    "rk4_simulate",
    "rk4_step",
]
