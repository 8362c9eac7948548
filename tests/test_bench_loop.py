"""The closed-loop benchmark's measurement of the time spent in compiled code."""

from __future__ import annotations

from tdacm.bench.loop import LOOP_CASES, compiled_share


def test_compiled_share_finds_the_kernels_and_bounds_the_real_time_factor():
    c = compiled_share(LOOP_CASES["analytic"], duration=0.4, top=20)
    top = c["top"]
    # each block's compiled step once per period: the plant's (its substeps inside), the
    # perception's (the compiled IPPE inside), the servo's (the target filter inside) and the
    # controller's
    assert abs(top["tdacm.loop.plant.plant_step"]["calls_per_period"] - 1.0) < 0.1
    for step in ("loop.perception.perceive", "loop.servo.servo_perceive",
                 "loop.servo.servo_command", "control.hierarchical.controller_step"):  # fmt: skip
        assert abs(top[f"tdacm.{step}"]["calls_per_period"] - 1.0) < 0.1, step
    assert not any("numpy" in k or "builtins" in k for k in top)  # no Python-level entries
    assert 0.0 < c["compiled_ms"] < c["period_ms"]
    assert abs(c["cap_real_time_factor"] - 20.0 / c["compiled_ms"]) < 1e-9  # dt = 20 ms
    assert (
        abs(sum(v["ms_per_period"] for v in top.values()) - c["compiled_ms"])
        < 0.5 * c["compiled_ms"]
    )


def test_env_bench_reports_medians_and_ratios_to_the_targets():
    from tdacm.bench.env import TARGETS, env_bench

    e = env_bench(steps=40, repeats=1, progress=lambda *_: None)
    for k in ("single_steps_per_s", "async2_steps_per_s", "reset_ms"):
        assert e[k] > 0
    assert (
        e["ratios"]["single_steps_per_s"] == e["single_steps_per_s"] / TARGETS["single_steps_per_s"]
    )
    assert e["ratios"]["reset_ms"] == TARGETS["reset_ms"] / e["reset_ms"]
