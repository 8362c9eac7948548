"""Benchmarks (``tdacm bench``): the model's timings and accuracy (:mod:`.model`), the closed
loop's real-time factor and cold start (:mod:`.loop`) and the estimator's plant-only harness
(:mod:`.estimation`); :func:`batch_times` and :func:`configure_logging` for the scripts of
``benchmarks/``."""

from .._log import configure_logging
from .._timing import batch_times
from .model import run_full_bench, run_model_bench

__all__ = ["batch_times", "configure_logging", "run_full_bench", "run_model_bench"]
