"""Every campaign spec shipped in ``examples/campaigns`` loads, and the scenario of its first
runs (with the sampled overrides) passes the schema's validation."""

from pathlib import Path

import pytest

from tdacm.campaign.runner import sample_overrides
from tdacm.campaign.spec import load_spec
from tdacm.sim.scenario import load_scenario

SPECS = sorted((Path(__file__).parents[2] / "examples" / "campaigns").glob("*.toml"))


def test_specs_are_shipped():
    assert len(SPECS) >= 10


@pytest.mark.parametrize("path", SPECS, ids=[p.stem for p in SPECS])
def test_shipped_spec_validates(path):
    spec = load_spec(path)
    assert spec.runs >= 1
    base = load_scenario(spec.scenario)
    for seed in spec.run_seeds()[:3]:
        sc = base.with_overrides(sample_overrides(spec, base.data, int(seed)), path.name)
        assert sc.data["dt"] > 0
