"""Closed-loop simulation of the TD-ACM scenarios (see ``docs/control.md``)."""

from .assemble import Assembly, World, build_loop, build_world
from .runner import SafetyMonitor, Simulation, normalized_rmse, run_scenario
from .scenario import (
    Scenario,
    ScenarioError,
    list_scenarios,
    load_scenario,
    parse_scenario,
)

__all__ = [
    "Assembly",
    "World",
    "build_loop",
    "build_world",
    "SafetyMonitor",
    "Scenario",
    "ScenarioError",
    "Simulation",
    "list_scenarios",
    "load_scenario",
    "normalized_rmse",
    "parse_scenario",
    "run_scenario",
]
