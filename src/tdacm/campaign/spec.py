"""Campaign specifications: a scenario, distributions over its parameters, a number of runs.

A spec is a TOML file::

    scenario = "paper-in-fov"     # a shipped scenario name or a scenario TOML path
    runs = 200
    seed = 2026                   # master seed: run i gets its own seed from SeedSequence(seed)
    duration = 5.0                # optional, overrides the scenario's
    success_rmse = 0.01           # a run succeeds if it ends at or below this normalized RMSE
    success_window = 1.0          # optional: ... if the RMS of the normalized RMSE over its
                                  # last 1 s is at or below success_rmse (unset: the last sample)
    success_hold_force_rms = 0.2  # optional, servoing into contact ([touch]): ... if it held
                                  # the force for touch.hold_time within 20 % RMS with the
                                  # task's image error (C_L) <= success_rmse throughout it
    batched = "auto"              # optional: true | false | "auto" (default): the batched
                                  # engine where it runs the scenario and the sampled keys

    [distributions]
    # keys are "section.key" paths into the scenario (docs/scenario-reference.md)
    "initial.q"          = { kind = "normal", std = [0, 0, 0.05, 0.1, 0.1, 0.1, 0.05, 0.05] }
    "model.perturbation" = { kind = "fixed", value = 0.1 }
    "sensors.pixel_noise" = { kind = "fixed", value = 1.0 }
    "sensors.dropout"    = { kind = "uniform", low = 0.0, high = 0.05 }
    "sensors.latency_steps" = { kind = "choice", values = [0, 1] }

Kinds: ``fixed`` (``value``), ``normal`` (``std``, optional ``mean``; added to the scenario's
value when ``relative = false`` (default) — a perturbation around the nominal — or multiplying
``1 + N(mean, std)`` when ``relative = true``), ``uniform`` (``low``, ``high``; same ``relative``
rule: absolute values unless ``offset = true``), ``choice`` (``values``: numbers, strings or
booleans, each a valid value of the key), ``truncnormal`` (``mean``, ``std``, optional ``low``,
``high``: absolute values drawn from ``N(mean, std)`` and redrawn, from the run's seeded
generator, until they lie in ``[low, high]`` and in the key's valid range).  Vectors take vector
parameters of the key's length or scalars (broadcast).

The file is the record :class:`CampaignSpecConfig` (one :class:`DistributionConfig` per
distribution), validated as a scenario is: an error is one line naming the dotted key, and
``tdacm schema --campaign`` prints its JSON Schema. The checks that need the scenario (the key
exists, vector lengths, the key's range) follow in :func:`parse_spec`.

The valid range of a key comes from the scenario's records (:func:`tdacm.sim.config.bounds`):
a distribution whose samples can leave it (a ``normal`` on ``sensors.pixel_noise``, which must
be >= 0; a ``uniform`` or ``choice`` reaching outside) is rejected when the spec is loaded,
naming the key; ``truncnormal`` is the way to draw a bell-shaped value on a bounded key.
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import ValidationError, model_validator

from .._config import ConfigModel, Field
from ..sim.runner import SUCCESS_RMSE


class CampaignSpecError(ValueError):
    """An invalid campaign specification."""


KINDS = {
    "fixed": {"value"},
    "normal": {"std", "mean", "relative"},
    "uniform": {"low", "high", "offset"},
    "choice": {"values"},
    "truncnormal": {"mean", "std", "low", "high"},
}

#: the parameters a kind must have (the others of :data:`KINDS` are optional)
NEEDS = {"fixed": ("value",), "normal": ("std",), "uniform": ("low", "high"),
         "choice": ("values",), "truncnormal": ("mean", "std")}  # fmt: skip

#: draws of a truncnormal before giving up (the window must hold some of the normal's mass)
MAX_REDRAWS = 10_000

Param = float | list[float]


class DistributionConfig(ConfigModel):
    """One entry of ``[distributions]``: ``kind`` and its parameters (module docstring); a
    vector parameter has the key's length, a scalar is broadcast."""

    kind: Literal["fixed", "normal", "uniform", "choice", "truncnormal"] = Field(
        description="the distribution"
    )
    value: Param | bool | str | None = Field(None, description="fixed: the value")
    values: list[Param | bool | str] | None = Field(
        None, min_length=1, description="choice: the values drawn from (uniformly)"
    )
    mean: Param | None = Field(
        None, description="normal: mean of the draw (default 0); truncnormal: its mean"
    )
    std: Param | None = Field(None, description="normal, truncnormal: standard deviation")
    low: Param | None = Field(
        None, description="uniform: lower end; truncnormal: lower end of the window (optional)"
    )
    high: Param | None = Field(
        None, description="uniform: upper end; truncnormal: upper end of the window (optional)"
    )
    relative: bool = Field(
        False, description="normal: multiply the scenario's value by 1 + N(mean, std)"
    )
    offset: bool = Field(False, description="uniform: add the draw to the scenario's value")

    @model_validator(mode="after")
    def _parameters(self):
        given = self.model_fields_set - {"kind"}
        extra = given - KINDS[self.kind]
        if extra:
            raise ValueError(f"unknown parameters {sorted(extra)} for kind {self.kind!r}")
        missing = [k for k in NEEDS[self.kind] if k not in given]
        if missing:
            raise ValueError(f"kind {self.kind!r} needs {' and '.join(repr(k) for k in missing)}")
        return self


class CampaignSpecConfig(ConfigModel):
    """A campaign spec file (``tdacm campaign SPEC``, docs/campaigns.md)."""

    scenario: str = Field(description="a shipped scenario name or a scenario TOML path")
    runs: int = Field(ge=1, description="number of runs")
    seed: int = Field(
        0, ge=0, description="master seed: run i gets its own seed from SeedSequence(seed)"
    )
    duration: float | None = Field(
        None, gt=0, description="s, overrides the scenario's duration (unset: the scenario's)"
    )
    success_rmse: float = Field(
        SUCCESS_RMSE, gt=0, description="a run succeeds if it ends at or below this normalized RMSE"
    )
    success_window: float | None = Field(
        None,
        gt=0,
        description="s: judge the RMS of the normalized RMSE over the run's last seconds "
        "(unset: its last sample)",
    )
    success_hold_force_rms: float | None = Field(
        None,
        gt=0,
        description="servoing into contact: a run succeeds if it held the force for "
        "touch.hold_time within this fraction RMS, the task's image error (the tip camera's "
        "points to the reference in C_L) <= success_rmse throughout the hold",
    )
    distributions: dict[str, DistributionConfig] = Field(
        {}, description="dotted scenario key -> its distribution"
    )
    batched: bool | Literal["auto"] = Field(
        "auto",
        description="run the campaign on the batched engine (chunks of runs as one batch of "
        "worlds): true, false (the block loop, one run at a time) or 'auto' (batched where "
        "the engine runs the scenario and every sampled key, else the block loop)",
    )

    @model_validator(mode="after")
    def _rules(self):
        w, d = self.success_window, self.duration
        if w is not None and d is not None and w > d:
            raise ValueError(f"success_window ({w} s) must not exceed duration ({d} s)")
        if self.success_hold_force_rms is not None and w is not None:
            raise ValueError("success_hold_force_rms and success_window are two rules: give one")
        return self


def json_schema() -> dict:
    """The JSON Schema of a campaign spec file (``tdacm schema --campaign``)."""
    schema = CampaignSpecConfig.model_json_schema()
    schema["title"] = "tdacm campaign spec"
    return schema


@dataclass
class CampaignSpec:
    scenario: str
    runs: int
    seed: int
    distributions: dict
    duration: float | None
    success_rmse: float
    source: str = "<spec>"
    #: s: judge a run on the RMS of its normalized RMSE over its last ``success_window``
    #: seconds (:func:`tdacm.sim.runner.late_rmse`); ``None``: on its last sample
    success_window: float | None = None
    #: servoing into contact: a run succeeds when it held the force for the scenario's
    #: ``touch.hold_time`` with the true force's RMS error at most this fraction of the
    #: desired force and the task's image error (the detected tip-camera points to the
    #: reference snapshot in C_L) at most ``success_rmse`` throughout the hold (the summary's
    #: ``hold_force_rms_rel``, ``hold_image_error_max``); ``None``: the RMSE rule
    success_hold_force_rms: float | None = None
    #: the engine: ``True`` the batched engine (:mod:`tdacm.campaign.batched`), ``False`` the
    #: block loop, ``"auto"`` batched where supported; how the runs execute, not what they
    #: are, so not in :meth:`fingerprint` (a stored campaign resumes on either)
    batched: bool | str = CampaignSpecConfig.model_fields["batched"].default

    def as_dict(self) -> dict:
        out = {
            "scenario": self.scenario,
            "runs": self.runs,
            "seed": self.seed,
            "duration": self.duration,
            "success_rmse": self.success_rmse,
            "distributions": self.distributions,
        }
        if self.success_window is not None:  # (absent: the fingerprints of older specs hold)
            out["success_window"] = self.success_window
        if self.success_hold_force_rms is not None:
            out["success_hold_force_rms"] = self.success_hold_force_rms
        return out

    def fingerprint(self) -> str:
        """Hash of everything that determines the runs (to refuse resuming another spec)."""
        return hashlib.sha256(json.dumps(self.as_dict(), sort_keys=True).encode()).hexdigest()[:16]

    def run_seeds(self) -> np.ndarray:
        """Per-run seeds: run ``i`` always gets the same seed for a given master seed."""
        children = np.random.SeedSequence(self.seed).spawn(self.runs)
        return np.array(
            [int(c.generate_state(1, dtype=np.uint32)[0]) for c in children], dtype=np.int64
        )


def _err(source, msg):
    raise CampaignSpecError(f"{source}: {msg}")


def _num(source, where, v):
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        _err(source, f"{where} must be a finite number, got {v!r}")
    return float(v)


def _vec_or_scalar(source, where, v, length):
    if isinstance(v, list):
        if length is None:
            _err(source, f"{where}: this key is a scalar, got a list")
        if length >= 0 and len(v) != length:
            _err(source, f"{where} must have {length} entries, got {len(v)}")
        return [_num(source, where, x) for x in v]
    return _num(source, where, v)


def _side(d: dict, side: str):
    """A truncnormal's ``low``/``high`` (``None``: unbounded on that side)."""
    v = d.get(side)
    return (-math.inf if side == "low" else math.inf) if v is None else v


def _key_bounds(key: str):
    from ..sim.config import bounds

    try:
        return bounds(key)
    except KeyError:  # not a scenario value with a range
        return None, False, None, False


def _check_range(source, where, key, d: dict, base) -> None:
    """Reject a distribution whose samples can leave ``key``'s valid range (from the records),
    and text/boolean values that are not valid values of the key."""
    kind = d["kind"]
    if isinstance(base, bool | str):
        from pydantic import ValidationError

        from ..sim.config import ScenarioConfig, error_line

        vals = [d["value"]] if kind == "fixed" else d["values"]
        for v in vals:
            node = v
            for part in reversed(key.split(".")):
                node = {part: node}
            try:
                ScenarioConfig.model_validate(node)
            except ValidationError as exc:
                _err(source, f"{where}: {error_line(exc)}")
        return
    lo, lo_in, hi, hi_in = _key_bounds(key)
    if lo is None and hi is None:
        return
    from ..sim.config import range_text

    rng = range_text(key)

    def inside(x) -> bool:
        x = np.asarray(x, float)
        ok = np.ones(x.shape, bool)
        if lo is not None:
            ok &= (x >= lo) if lo_in else (x > lo)
        if hi is not None:
            ok &= (x <= hi) if hi_in else (x < hi)
        return bool(np.all(ok))

    b = np.asarray(base, float)
    if kind == "fixed":
        ends = [d["value"]]
    elif kind == "choice":
        ends = d["values"]
    elif kind == "uniform":
        ends = [d["low"], d["high"]]
        if d["offset"]:
            ends = [b + np.asarray(e, float) for e in ends]
    elif kind == "normal":
        spread = np.asarray(d["std"], float) * (np.abs(b) if d["relative"] else 1.0)
        if np.any(spread > 0):
            _err(
                source,
                f"{where}: a normal distribution can leave the valid range of {key} ({rng}); "
                "use kind = 'truncnormal' (mean, std, low, high)",
            )
        return
    else:  # truncnormal: the window must meet the key's range
        lo_w = np.maximum(_side(d, "low"), -np.inf if lo is None else lo)
        hi_w = np.minimum(_side(d, "high"), np.inf if hi is None else hi)
        if np.any(hi_w < lo_w):
            _err(source, f"{where}: [low, high] lies outside the valid range of {key} ({rng})")
        return
    for e in ends:
        if not inside(e):
            _err(source, f"{where}: {key} must be {rng}, the distribution gives {e!r}")


def parse_spec(
    text: str, source: str = CampaignSpec.source, scenario_defaults: dict | None = None
) -> CampaignSpec:
    """Parse and validate a campaign spec (TOML text).  ``scenario_defaults`` (the scenario's
    resolved data) lets the validation check every distribution key and vector length."""
    from ..sim.config import error_line

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CampaignSpecError(f"{source}: invalid TOML: {exc}") from None
    try:
        rec = CampaignSpecConfig.model_validate(data)
    except ValidationError as exc:
        raise CampaignSpecError(f"{source}: {error_line(exc, CampaignSpecConfig)}") from None
    dists = {k: v.model_dump(exclude_unset=True) for k, v in rec.distributions.items()}
    clean = {}
    for key, d in dists.items():
        where = f"distributions.{key!r}"
        parts = key.split(".")
        if len(parts) < 2 or not all(parts):
            _err(source, f"{where}: keys are dotted paths, e.g. 'initial.q' or 'robot.rod.length'")
        length = -1  # unknown until checked against the scenario
        text_value = False  # a string or boolean parameter: kinds 'fixed' and 'choice' only
        if scenario_defaults is not None:
            table = scenario_defaults
            for i, part in enumerate(parts[:-1]):
                if not isinstance(table.get(part), dict):
                    _err(
                        source, f"{where}: the scenario has no section [{'.'.join(parts[: i + 1])}]"
                    )
                table = table[part]
            name = parts[-1]
            if isinstance(table.get(name), dict):
                _err(source, f"{where}: [{key}] is a section; name one of its keys")
            if name not in table:
                known = sorted(k for k, v in table.items() if not isinstance(v, dict))
                _err(
                    source,
                    f"{where}: [{'.'.join(parts[:-1])}] has no key {name!r} (known: {known})",
                )
            base = table[name]
            length = None
            if base is None and key == "initial.qd":  # unset: zero velocity of len(initial.q)
                base = [0.0] * len(scenario_defaults["initial"]["q"])
            if base is None:
                _err(source, f"{where}: {key} has no value in the scenario; it cannot be sampled")
            if isinstance(base, list):
                length = len(base)
            elif isinstance(base, bool | str):
                text_value = True
            elif not isinstance(base, int | float):
                _err(source, f"{where}: {key} = {base!r} cannot be sampled")
        if scenario_defaults is None and isinstance(d, dict):
            # first pass, the scenario not read yet: a string/boolean value marks a text key
            vals = [d.get("value")] if d.get("kind") == "fixed" else d.get("values") or []
            text_value = bool(vals) and all(isinstance(v, bool | str) for v in vals)
            base = vals[0] if text_value else None
        kind = d["kind"]
        out = {"kind": kind}
        if text_value:
            if kind not in ("fixed", "choice"):
                _err(source, f"{where}: {key} is not numeric; use kind 'fixed' or 'choice'")
            vals = [d.get("value")] if kind == "fixed" else d.get("values")
            if (
                not isinstance(vals, list)
                or not vals
                or any(type(v) is not type(base) for v in vals)
            ):
                _err(source, f"{where}: give {type(base).__name__} value(s) for {key}, got {d!r}")
            out["value" if kind == "fixed" else "values"] = vals[0] if kind == "fixed" else vals
        elif kind == "fixed":
            out["value"] = _vec_or_scalar(source, f"{where}.value", d["value"], length)
        elif kind == "normal":
            out["std"] = _vec_or_scalar(source, f"{where}.std", d["std"], length)
            if np.any(np.asarray(out["std"]) < 0):
                _err(source, f"{where}.std must be non-negative, got {d['std']!r}")
            out["mean"] = _vec_or_scalar(source, f"{where}.mean", d.get("mean", 0.0), length)
            out["relative"] = bool(d.get("relative", False))
        elif kind == "uniform":
            out["low"] = _vec_or_scalar(source, f"{where}.low", d["low"], length)
            out["high"] = _vec_or_scalar(source, f"{where}.high", d["high"], length)
            if np.any(np.asarray(out["high"]) < np.asarray(out["low"])):
                _err(source, f"{where}: high must be >= low")
            out["offset"] = bool(d.get("offset", False))
        elif kind == "truncnormal":
            out["mean"] = _vec_or_scalar(source, f"{where}.mean", d["mean"], length)
            out["std"] = _vec_or_scalar(source, f"{where}.std", d["std"], length)
            if np.any(np.asarray(out["std"]) < 0):
                _err(source, f"{where}.std must be non-negative, got {d['std']!r}")
            for side in ("low", "high"):  # optional: the key's range alone
                v = d.get(side)
                out[side] = (
                    None if v is None else _vec_or_scalar(source, f"{where}.{side}", v, length)
                )
            if np.any(np.asarray(_side(out, "high")) < np.asarray(_side(out, "low"))):
                _err(source, f"{where}: high must be >= low")
        else:
            vals = d["values"]
            out["values"] = [_vec_or_scalar(source, f"{where}.values", v, length) for v in vals]
        if scenario_defaults is not None:
            _check_range(source, where, key, out, base)
        clean[key] = out
    return CampaignSpec(
        rec.scenario, rec.runs, rec.seed, clean, rec.duration, rec.success_rmse, source,
        success_window=rec.success_window, success_hold_force_rms=rec.success_hold_force_rms,
        batched=rec.batched,
    )  # fmt: skip


def resolve_scenario(ref: str, spec_path: Path) -> str:
    """A spec's ``scenario``: a shipped name stays a name; a path (ends in ``.toml`` or has a
    folder) is resolved against the spec file's folder, not the current directory."""
    if ref.endswith(".toml") or "/" in ref or "\\" in ref:
        p = Path(ref).expanduser()
        if not p.is_absolute():
            p = (Path(spec_path).resolve().parent / p).resolve()
        return str(p)
    return ref


def load_spec(path) -> CampaignSpec:
    """Read a spec file and validate it against its scenario (resolved with
    :func:`resolve_scenario`; an unknown or invalid scenario, a directory or a non-UTF-8 file
    raise :class:`CampaignSpecError` naming the file and the key)."""
    from ..sim.assemble import build_world
    from ..sim.scenario import ScenarioError, check_run, load_scenario

    p = Path(path)
    if p.is_dir():
        raise CampaignSpecError(f"campaign spec {path} is a directory, not a TOML file")
    if not p.is_file():
        raise CampaignSpecError(f"campaign spec {path} does not exist")
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CampaignSpecError(f"campaign spec {p} is not UTF-8 text: {exc}") from None
    first = parse_spec(text, str(p))
    ref = resolve_scenario(first.scenario, p)
    try:
        scenario = load_scenario(ref)
        check_run(scenario, first.duration, flags=False)
        build_world(scenario)  # the checks against the built robot
    except ScenarioError as exc:
        raise CampaignSpecError(f"{p}: scenario = {first.scenario!r}: {exc}") from None
    spec = parse_spec(text, str(p), scenario.data)
    spec.scenario = ref
    return spec


def sample_overrides(spec: CampaignSpec, scenario_data: dict, run_seed: int) -> dict:
    """The scenario overrides of one run, drawn with ``default_rng(run_seed)`` (deterministic)."""
    rng = np.random.default_rng(run_seed)
    out: dict = {}
    for key in sorted(spec.distributions):
        d = spec.distributions[key]
        parts = key.split(".")
        table = scenario_data
        for part in parts[:-1]:
            table = table[part]
        base = table[parts[-1]]
        if base is None and key == "initial.qd":
            base = [0.0] * len(scenario_data["initial"]["q"])
        kind = d["kind"]
        if isinstance(base, bool | str):
            pyval = d["value"] if kind == "fixed" else d["values"][rng.integers(len(d["values"]))]
        else:
            pyval = _draw(d, base, rng, key)
        node = out
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = pyval
    return out


def _truncnormal(d: dict, shape, key: str, rng) -> np.ndarray:
    """``N(mean, std)`` redrawn where outside ``[low, high]`` and the key's valid range."""
    lo, lo_in, hi, hi_in = _key_bounds(key)
    mean = np.broadcast_to(np.asarray(d["mean"], float), shape)
    std = np.broadcast_to(np.asarray(d["std"], float), shape)
    low = np.broadcast_to(np.asarray(_side(d, "low"), float), shape)
    high = np.broadcast_to(np.asarray(_side(d, "high"), float), shape)

    def ok(x):
        good = (x >= low) & (x <= high)
        if lo is not None:
            good &= (x >= lo) if lo_in else (x > lo)
        if hi is not None:
            good &= (x <= hi) if hi_in else (x < hi)
        return good

    value = np.array(rng.normal(mean, std), dtype=float)
    for _ in range(MAX_REDRAWS):
        bad = ~ok(value)
        if not bad.any():
            return value
        value[bad] = rng.normal(mean, std)[bad] if value.ndim else rng.normal(mean, std)
    raise CampaignSpecError(
        f"{key}: truncnormal found no value in its window after {MAX_REDRAWS} draws"
    )


def _draw(d: dict, base, rng, key: str = "") -> object:
    base_arr = np.asarray(base if base is not None else 0.0, dtype=float)
    shape = base_arr.shape
    kind = d["kind"]
    if kind == "fixed":
        value = np.broadcast_to(np.asarray(d["value"], float), shape)
    elif kind == "normal":
        draw = rng.normal(np.broadcast_to(d["mean"], shape), np.broadcast_to(d["std"], shape))
        value = base_arr * (1.0 + draw) if d["relative"] else base_arr + draw
    elif kind == "uniform":
        draw = rng.uniform(np.broadcast_to(d["low"], shape), np.broadcast_to(d["high"], shape))
        value = base_arr + draw if d["offset"] else draw
    elif kind == "truncnormal":
        value = _truncnormal(d, shape, key, rng)
    else:
        value = np.broadcast_to(
            np.asarray(d["values"][rng.integers(len(d["values"]))], float), shape
        )
    value = np.array(value, dtype=float)
    if isinstance(base, int) and not isinstance(base, bool):
        return int(round(float(value)))
    if shape == ():
        return float(value)
    return value.tolist()


def to_toml(data: dict) -> str:
    """A run's scenario overrides (nested sections) as TOML."""
    from ..sim.scenario import dict_to_toml

    return dict_to_toml(data)


def succeeded(spec: CampaignSpec, arrays: dict, summary: dict) -> bool:
    """A run's success: not terminated (safety monitor, force limit, ...) and, with
    ``spec.success_hold_force_rms``, the hold criterion of :func:`held`; else its normalized RMSE at or
    below ``spec.success_rmse``, either its last sample or, with ``spec.success_window``, the
    RMS of the samples of its last ``success_window`` seconds (a criterion that the wandering
    of the RMSE after convergence does not decide by one sample)."""
    if summary.get("terminated"):
        return False
    if spec.success_hold_force_rms is not None:
        return held(spec, summary)
    if spec.success_window is None:
        value = summary.get("final_rmse")
    else:
        from ..sim.runner import late_rmse

        value = late_rmse(arrays["t"], arrays["rmse"], spec.success_window)
    return bool(value is not None and np.isfinite(value) and value <= spec.success_rmse)


def held(spec: CampaignSpec, summary: dict) -> bool:
    """Servoing into contact (``spec.success_hold_force_rms``): the hold lasted the
    scenario's ``touch.hold_time`` (to half a period), the true force's RMS error over it is
    at most that fraction of the desired force and the normalized RMSE stayed at or below
    ``spec.success_rmse`` (:func:`tdacm.sim.runner.touch_summary`)."""
    dur, hold_time = summary.get("hold_duration"), summary.get("touch_hold_time")
    rms, img = summary.get("hold_force_rms_rel"), summary.get("hold_image_error_max")
    if None in (dur, hold_time, rms, img):
        return False
    return bool(
        dur >= hold_time - 0.5 * summary["dt"]
        and rms <= spec.success_hold_force_rms
        and img <= spec.success_rmse
    )
