"""Shared fixtures for the vision tests: renderers (created once per module or session) and
a small kinematic stand-in for the coupled model (same API as ``tdacm.paper_system()``)."""

from __future__ import annotations

import pytest

from tdacm.vision import PlanarRenderer, PyBulletRenderer, SceneConfig
from tdacm.vision.targets import PAPER_MARKER, PAPER_PATTERN

from .vision_helpers import FakeSystem


@pytest.fixture(scope="session")
def fake_system():
    return FakeSystem()


@pytest.fixture(scope="session")
def marker_scene():
    return SceneConfig(target=PAPER_MARKER)


@pytest.fixture(scope="session")
def pattern_scene():
    return SceneConfig(target=PAPER_PATTERN)


@pytest.fixture(scope="module")
def tiny_marker(marker_scene):
    with PyBulletRenderer(marker_scene, backend="tiny") as r:
        yield r


@pytest.fixture(scope="module")
def tiny_pattern(pattern_scene):
    with PyBulletRenderer(pattern_scene, backend="tiny", arm=None) as r:
        yield r


@pytest.fixture(scope="session")
def planar_marker(marker_scene):
    return PlanarRenderer(marker_scene)


@pytest.fixture(scope="session")
def planar_pattern(pattern_scene):
    return PlanarRenderer(pattern_scene)


def pytest_terminal_summary(terminalreporter):
    """Report the closed-loop success rates measured by test_ibvs.py in the summary."""
    from .vision_helpers import LOOP_REPORT

    if LOOP_REPORT:
        terminalreporter.section("vision: IBVS closed-loop success rates")
        for line in LOOP_REPORT:
            terminalreporter.write_line(line)
