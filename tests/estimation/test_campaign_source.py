"""``estimation.source`` (and other string/boolean keys) in campaign distributions (the spec
parser is main's; these check the estimation keys through it)."""

import pytest

from tdacm.campaign.spec import CampaignSpecError, parse_spec, sample_overrides
from tdacm.sim.scenario import load_scenario

BASE = load_scenario("paper-in-fov").data


def spec(dist):
    return parse_spec(f'scenario = "paper-in-fov"\nruns = 4\n[distributions]\n{dist}\n', "t", BASE)


def test_fixed_and_choice_of_a_string_key():
    s = spec('"estimation.source" = { kind = "fixed", value = "estimated" }')
    assert sample_overrides(s, BASE, 1) == {"estimation": {"source": "estimated"}}
    s = spec('"estimation.source" = { kind = "choice", values = ["true", "estimated"] }')
    picks = {sample_overrides(s, BASE, k)["estimation"]["source"] for k in range(20)}
    assert picks == {"true", "estimated"}
    # reproducible from the run seed
    assert sample_overrides(s, BASE, 7) == sample_overrides(s, BASE, 7)
    s = spec('"sensors.pose_enabled" = { kind = "fixed", value = false }')
    assert sample_overrides(s, BASE, 0) == {"sensors": {"pose_enabled": False}}


@pytest.mark.parametrize(
    "dist, key",
    [
        ('"estimation.source" = { kind = "uniform", low = 0, high = 1 }', "estimation.source"),
        ('"estimation.source" = { kind = "fixed", value = 1.0 }', "estimation.source"),
        ('"sensors.pose_enabled" = { kind = "choice", values = ["yes"] }', "sensors.pose_enabled"),
    ],
)
def test_categorical_errors_name_the_key(dist, key):
    with pytest.raises(CampaignSpecError, match=key.replace(".", r"\.")):
        spec(dist)
