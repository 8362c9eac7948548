"""Wall-clock timing of small functions for the benchmarks."""

from __future__ import annotations

import time


def batch_times(fn, number: int, repeats: int) -> list:
    """``repeats`` batch means (s per call) of ``number`` calls of ``fn`` each
    (``time.perf_counter``); the spread of the batches shows the machine's background load."""
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        out.append((time.perf_counter() - t0) / number)
    return out
