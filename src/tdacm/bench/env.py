"""Gymnasium env timings (``tdacm bench``, section ``env``; ``benchmarks/bench_loop.py``).

The env as documented, ``gym.make("tdacm/TipServo-v0")`` (analytic cameras, no renderer):

* ``single``: env steps per second of one env (zero twist; an episode that ends is reset);
* ``reset``: milliseconds of ``reset(seed=k)`` (the loop reused and reseeded);
* ``async2``: env steps per second of ``AsyncVectorEnv`` with two worker processes (a
  vector step counts two env steps).

Each figure is the median of ``repeats`` measurements after a warm-up, with its ratio to the
target (:data:`TARGETS`; a ratio >= 1 meets it). On a shared machine the wall-clock figures
follow the load; the CPU time per env step (``single_cpu_ms_per_step``; for the vector, the
workers' and the parent's CPU time over the vector's steps, ``async2_cpu_ms_per_env_step``) is
what the env itself costs, and ``2000 / async2_cpu_ms_per_env_step`` bounds what two free
cores could give.
"""

from __future__ import annotations

import time

import numpy as np

#: single env steps/s, 2 async envs env-steps/s, reset ms (lower is better)
TARGETS = {"single_steps_per_s": 300.0, "async2_steps_per_s": 1000.0, "reset_ms": 20.0}


def _make():
    import gymnasium as gym

    import tdacm.envs  # noqa: F401  (registers the id)

    return gym.make("tdacm/TipServo-v0")


def _steps_per_s(env, steps: int, cpu: list | None = None) -> float:
    a = np.zeros(6, np.float32)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()
    if cpu is not None:
        cpu.append((time.process_time() - c0) / steps * 1e3)
    return steps / (time.perf_counter() - t0)


def env_bench(steps: int = 1000, repeats: int = 5, progress=print) -> dict:
    """The three figures of the module docstring (medians of ``repeats``)."""
    import gymnasium as gym

    progress(f"env: one env, {repeats} x {steps} steps; reset(seed) x 20")
    env = _make()
    env.reset(seed=0)
    _steps_per_s(env, 100)  # warm-up
    cpu = []
    single = [_steps_per_s(env, steps, cpu) for _ in range(repeats)]
    resets = []
    for k in range(21):
        t0 = time.perf_counter()
        env.reset(seed=k)
        resets.append((time.perf_counter() - t0) * 1e3)
    resets = resets[1:]
    env.close()
    progress(f"env: AsyncVectorEnv of 2, {repeats} x {steps // 2} vector steps")
    import resource

    def cpu_s():
        c = resource.getrusage(resource.RUSAGE_CHILDREN)  # the workers, once joined
        return time.process_time() + c.ru_utime + c.ru_stime

    cpu0 = cpu_s()
    total = 0
    envs = gym.vector.AsyncVectorEnv([_make] * 2)
    try:
        envs.reset(seed=0)
        a = np.zeros((2, 6), np.float32)
        for _ in range(50):
            envs.step(a)
        total += 100
        vec = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            for _ in range(steps // 2):
                envs.step(a)
            vec.append(2 * (steps // 2) / (time.perf_counter() - t0))
            total += 2 * (steps // 2)
    finally:
        envs.close()
    vec_cpu = (cpu_s() - cpu0) / total * 1e3  # includes the workers' start and reset
    res = {
        "single_steps_per_s": float(np.median(single)),
        "single_all": single,
        "single_cpu_ms_per_step": float(np.median(cpu)),
        "reset_ms": float(np.median(resets)),
        "reset_ms_max": float(np.max(resets)),
        "async2_steps_per_s": float(np.median(vec)),
        "async2_all": vec,
        "async2_cpu_ms_per_env_step": vec_cpu,
        "repeats": repeats,
        "steps": steps,
    }
    res["ratios"] = {
        "single_steps_per_s": res["single_steps_per_s"] / TARGETS["single_steps_per_s"],
        "async2_steps_per_s": res["async2_steps_per_s"] / TARGETS["async2_steps_per_s"],
        "reset_ms": TARGETS["reset_ms"] / res["reset_ms"],
    }
    res["targets"] = TARGETS
    progress(
        f"  one env {res['single_steps_per_s']:.0f} steps/s, 2 async "
        f"{res['async2_steps_per_s']:.0f} env-steps/s, reset {res['reset_ms']:.2f} ms"
    )
    return res


#: the vector env's env-steps/s at 256 worlds (the speed target; a ratio >= 1 meets it)
VECTOR_TARGET = 8000.0


def vector_bench(
    num_envs=(1, 16, 64, 256),
    threads=(1, 2),
    env_steps: int = 4096,
    repeats: int = 3,
    progress=print,
) -> dict:
    """Env steps per second of the vector env on the batched engine,
    ``gym.make_vec("tdacm/TipServo-v0", num_envs=N, vectorization_mode="vector_entry_point")``
    with uniform random twists (a new array per step; a world that ends is reset by the env's
    autoreset), for each ``N`` of ``num_envs`` and each thread count of ``threads``: the
    median of ``repeats`` runs of about ``env_steps`` env steps (``env_steps // N`` vector
    steps, at least 10) after a warm-up of 10 vector steps; with the CPU time per env step
    (the process's, all threads). Rows ``{"num_envs", "threads", "steps_per_s", "all",
    "cpu_us_per_env_step"}``; ``ratio``: the best figure at 256 worlds over
    :data:`VECTOR_TARGET`."""
    import gymnasium as gym

    import tdacm.envs  # noqa: F401  (registers the id)

    rows = []
    rng = np.random.default_rng(0)
    for n in num_envs:
        env = gym.make_vec("tdacm/TipServo-v0", num_envs=n, vectorization_mode="vector_entry_point")
        try:
            env.reset(seed=0)
            vsteps = max(10, env_steps // n)
            for t in threads:
                env.unwrapped.threads = t
                for _ in range(10):  # warm-up
                    env.step(rng.uniform(-1, 1, (n, 6)).astype(np.float32))
                runs, cpus = [], []
                for _ in range(repeats):
                    t0, c0 = time.perf_counter(), time.process_time()
                    for _ in range(vsteps):
                        env.step(rng.uniform(-1, 1, (n, 6)).astype(np.float32))
                    runs.append(n * vsteps / (time.perf_counter() - t0))
                    cpus.append((time.process_time() - c0) / (n * vsteps) * 1e6)
                rows.append(
                    {
                        "num_envs": n,
                        "threads": t,
                        "steps_per_s": float(np.median(runs)),
                        "all": runs,
                        "cpu_us_per_env_step": float(np.median(cpus)),
                    }
                )
                progress(
                    f"  vector env N={n:4d} threads={t}: {rows[-1]['steps_per_s']:8.0f} "
                    f"env-steps/s, {rows[-1]['cpu_us_per_env_step']:.0f} us CPU per env step"
                )
        finally:
            env.close()
    at256 = [r["steps_per_s"] for r in rows if r["num_envs"] == 256]
    return {
        "rows": rows,
        "repeats": repeats,
        "target_256": VECTOR_TARGET,
        "ratio": max(at256) / VECTOR_TARGET if at256 else None,
    }
