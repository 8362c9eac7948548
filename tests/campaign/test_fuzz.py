"""A short fuzz campaign (tdacm.campaign.fuzz; benchmarks/fuzz.py runs thousands): random
robots, sensors, initial states and actions end every episode at its duration or with a named
Termination, never with an exception."""

import numpy as np

from tdacm.campaign.fuzz import COMPLETED, POLICIES, REJECTED, count, draw_case, fuzz
from tdacm.loop import Termination


def test_draws_cover_both_camera_modes_both_states_and_the_ranges():
    rng = np.random.default_rng(0)
    cases = [draw_case(rng) for _ in range(60)]
    over = [o for _, o in cases]
    assert {n for n, _ in cases} == {"paper-in-fov", "ground-test-a"}
    assert {o["cameras"]["local_renderer"] for o in over} == {"analytic", "planar"}
    assert {o["estimation"]["source"] for o in over} == {"true", "estimated"}
    noise = [o["sensors"]["pixel_noise"] for o in over]
    assert min(noise) == 0.0 and max(noise) > 100 and max(noise) <= 200
    assert max(o["sensors"]["dropout"] for o in over) <= 0.9
    assert max(o["sensors"]["latency_steps"] for o in over) <= 10


def test_short_fuzz_campaign_has_no_exception_and_names_every_end():
    out = fuzz(30, seed=3, duration=(0.3, 0.6))
    episodes = [o for o in out if o.outcome != REJECTED]
    assert len(episodes) >= 30
    errors = [o.error for o in episodes if o.outcome == "exception"]
    assert not errors, errors[0]
    named = {str(t) for t in Termination} | {COMPLETED}
    assert set(count(episodes)) <= named
    for o in episodes:  # an early end always carries its reason in words
        assert (o.outcome == COMPLETED) == (o.reason is None), o
    assert {o.policy for o in episodes} <= set(POLICIES)
