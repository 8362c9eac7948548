"""Benchmarks (``tdacm bench``): the model's timings and accuracy (:mod:`.model`) and the closed
loop's real-time factor and cold start (:mod:`.loop`)."""

from .model import run_full_bench, run_model_bench

__all__ = ["run_full_bench", "run_model_bench"]
