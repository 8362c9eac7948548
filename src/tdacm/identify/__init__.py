"""System identification of a TD-ACM from recorded trajectories (``docs/identify.md``).

Estimate physical parameters (the rod's Young's modulus and damping, the tip mass, the tendon
moment arm and friction, the drone's mass, inertia and thrust constant, the tip camera's offset)
by fitting the model's simulated motion to what a lab measures (motion capture of the drone
and the tip, tendon tensions, optionally the tip camera's pixels): multiple shooting on the
system's RK4 (or ROS34PW2 for stiff bases), solved by Levenberg-Marquardt with the windows'
states eliminated block by block (:mod:`tdacm.identify.fit`, :mod:`tdacm.identify.solve`).
"""

from .data import Recording, RecordingInputError, load_recording
from .experiments import DEFAULT_TRUTH, EXPERIMENTS, NOISE, synthesize
from .fit import Identification, Problem, identify, identify_staged
from .observability import fisher_report
from .params import MAIN_PARAMETERS, PARAMETERS, parse_params
from .report import robot_toml, truth_errors, write_outputs

__all__ = [
    "DEFAULT_TRUTH",
    "EXPERIMENTS",
    "Identification",
    "MAIN_PARAMETERS",
    "NOISE",
    "PARAMETERS",
    "Problem",
    "Recording",
    "RecordingInputError",
    "fisher_report",
    "identify",
    "identify_staged",
    "load_recording",
    "parse_params",
    "robot_toml",
    "synthesize",
    "truth_errors",
    "write_outputs",
]
