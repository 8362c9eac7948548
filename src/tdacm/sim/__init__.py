"""Closed-loop simulation of the TD-ACM scenarios (see ``docs/control.md``)."""

from .runner import SafetyMonitor, Simulation, normalized_rmse, run_scenario
from .scenario import (
    Scenario,
    ScenarioError,
    list_scenarios,
    load_scenario,
    parse_scenario,
)

__all__ = [
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
