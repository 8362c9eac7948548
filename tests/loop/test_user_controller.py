"""A user's low-level controller is the loop's boundary: whatever it does (raise in ``step`` or
``reset``, return NaN, a short or long ``u``, the wrong types, nothing, or take its time), the
run ends at its duration or as an outcome (``Termination.CONTROLLER_FAILED`` naming the
controller and its own line), with the steps so far written and figures that can be drawn."""

import json
import time

import numpy as np
import pytest

from tdacm.cli import main
from tdacm.loop import ActuatorCommand, AdaptiveLowLevel, Termination
from tdacm.sim import Simulation, load_scenario
from tdacm.viz import plot_run_dir

FAST = {"cameras": {"local_renderer": "analytic", "global_renderer": "planar", "global_every": 0}}
AT = 3  # the period at which a faulty controller misbehaves


class Faulty:
    """The adaptive law, with the fault ``options["fault"]`` from period :data:`AT` on."""

    def __init__(self, context):
        self.inner = AdaptiveLowLevel(context)
        self.fault = context.options["fault"]
        self.k = 0

    def reset(self, estimate):
        if self.fault == "raise in reset":
            raise ValueError("cannot start")
        self.inner.reset(estimate)
        self.k = 0

    def step(self, estimate, command, dt):
        act = self.inner.step(estimate, command, dt)
        self.k += 1
        if self.k < AT:
            return act
        f = self.fault
        if f == "raise":
            raise RuntimeError("boom")  # the user's own line
        if f == "nan":
            return ActuatorCommand(act.u * np.nan, act.tau, act.q_ref)
        if f == "short u":
            return ActuatorCommand(act.u[:3], act.tau, act.q_ref)
        if f == "long u":
            return ActuatorCommand(np.r_[act.u, 1.0], act.tau, act.q_ref)
        if f == "2-D u":
            return ActuatorCommand(act.u[None, :], act.tau, act.q_ref)
        if f == "text u":
            return ActuatorCommand("thrust", act.tau, act.q_ref)
        if f == "None u":
            return ActuatorCommand(None, act.tau, act.q_ref)
        if f == "short tau":
            return ActuatorCommand(act.u, act.tau[:2], act.q_ref)
        if f == "None":
            return None
        if f == "array":
            return act.u
        if f == "list u":  # well-formed numbers in a list: accepted
            return ActuatorCommand(list(act.u), list(act.tau), act.q_ref)
        if f == "negative thrust":  # well-formed, but a rotor cannot pull
            return ActuatorCommand(np.r_[-5.0, act.u[1:]], act.tau, act.q_ref)
        if f == "tension over":  # well-formed, but beyond the tendon's max_tension (20 N)
            return ActuatorCommand(np.r_[act.u[:4], 1e3, act.u[5:]], act.tau, act.q_ref)
        if f == "slow":
            time.sleep(0.002)
            return act
        raise AssertionError(f)


FAILING = ["raise", "raise in reset", "short u", "long u", "2-D u", "text u", "None u",
           "short tau", "None", "array", "negative thrust", "tension over"]  # fmt: skip
#: the reason of a command outside the actuator ranges names the input and its range
OUT_OF_RANGE = {
    "negative thrust": "u[0] = -5 N (thrust of rotor 1), outside its range [0, 15] N",
    "tension over": "u[4] = 1000 N (tension of tendon 1), outside its range [0, 20] N",
}


def _scenario(fault):
    return load_scenario("paper-in-fov").with_overrides(
        {**FAST, "controller": {"class": f"{__name__}:Faulty", "options": {"fault": fault}}},
        "test",
    )


@pytest.mark.parametrize("fault", [*FAILING, "nan", "list u", "slow"])
def test_every_user_controller_fault_ends_as_an_outcome_with_its_data(tmp_path, fault):
    out = tmp_path / "run"
    arrays, summary = Simulation(_scenario(fault), duration=0.2).run(out)
    assert (out / "timeseries.npz").is_file() and (out / "summary.json").is_file()
    steps = 0 if fault == "raise in reset" else AT - 1
    if fault in FAILING:
        assert summary["termination"] == str(Termination.CONTROLLER_FAILED)
        assert f"{__name__}:Faulty" in summary["termination_reason"]
        assert OUT_OF_RANGE.get(fault, "") in summary["termination_reason"]
        assert len(arrays["t"]) == steps  # the periods before the fault, all logged
        assert arrays["u"].shape[1:] == ((8,) if steps else ())  # 4 thrusts, 4 tensions
    elif fault == "nan":
        assert summary["termination"] == str(Termination.NON_FINITE)
        assert len(arrays["t"]) == steps
    else:  # a list of numbers or a slow controller: a run to its end
        assert not summary["terminated"], summary["termination_reason"]
        assert summary["duration"] == pytest.approx(0.2)
    assert summary["controller"]["class"] == f"{__name__}:Faulty"
    assert summary["controller"]["file"] == __file__
    if fault in ("short u", "raise in reset"):  # the figures of what was written draw
        plot_run_dir(out, formats=("png",))


def test_a_raising_controller_names_its_own_line():
    sim = Simulation(_scenario("raise"), duration=0.2)
    _, summary = sim.run()
    f = summary["controller_failure"]
    assert f["file"] == __file__ and f["function"] == "step"
    assert f["code"] == 'raise RuntimeError("boom")  # the user\'s own line'
    assert "RuntimeError: boom" in f["error"] and f"{__file__}:{f['line']}" in f["error"]
    assert sim.result.controller_failure.where().startswith(f'File "{__file__}", line ')


def test_tdacm_run_with_a_raising_controller_exits_1_with_its_line(tmp_path, capsys):
    cfg = tmp_path / "cfg.toml"
    cfg.write_text(
        '[cameras]\nlocal_renderer = "analytic"\nglobal_renderer = "planar"\nglobal_every = 0\n'
        f'[controller]\nclass = "{__name__}:Faulty"\n[controller.options]\nfault = "raise"\n'
    )
    out = tmp_path / "run"
    code = main(["-q", "run", "paper-in-fov", "--config", str(cfg), "--duration", "0.2",
                 "--out", str(out)])  # fmt: skip
    cap = capsys.readouterr()
    assert code == 1
    summary = json.loads(cap.out)
    assert summary["termination"] == "controller failed"
    err = cap.err.strip().splitlines()
    assert len(err) == 2 and err[0].startswith("controller failed: controller "), err
    assert f"{__file__}:" in err[0] and err[1].strip().startswith("raise RuntimeError")
    assert "Traceback" not in cap.err
    for name in ("timeseries.npz", "summary.json", "actuation.png", "features.png"):
        assert (out / name).is_file(), name
