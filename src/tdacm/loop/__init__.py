"""The closed loop as blocks with explicit inputs and outputs (see ``docs/control.md``).

======================  ===================================================  ==================
block                   paper section                                        module
======================  ===================================================  ==================
plant                   coupled GVS dynamics, eq. (9); disturbances (test C)  :mod:`.plant`
sensors                 C_L and C_G (Table II) and their imperfections        :mod:`.sensors`
estimation              the state the controller uses                         :mod:`.estimation`
perception              detection -> normalized points, depths               :mod:`.perception`
servo                   virtual camera, advanced features, IBVS, recovery     :mod:`.servo`
low-level control       adaptive sliding-mode law, drone loop, allocation     :mod:`.lowlevel`
safety, logger          the error-growth rule; the run's time series          :mod:`.safety`, :mod:`.logger`
======================  ===================================================  ==================
"""

from .closed_loop import ClosedLoop, LoopStep, RunResult
from .data import (
    ActuatorCommand,
    CameraMeasurement,
    ControllerFailure,
    GlobalView,
    LocalView,
    PlantState,
    SensorReadings,
    ServoCommand,
    ServoEvent,
    StateEstimate,
    Termination,
)
from .lowlevel import AdaptiveLowLevel, PDGravityController, load_class
from .perception import Perception
from .plant import Disturbances, Plant
from .protocols import ControllerContext, Estimator, LowLevelController, Servo
from .safety import SafetyMonitor
from .sensors import AnalyticFrontEnd, CameraSensor, RenderedFrontEnd, Sensors
from .servo import VisualServo, normalized_rmse

__all__ = [
    "ActuatorCommand",
    "AdaptiveLowLevel",
    "PDGravityController",
    "AnalyticFrontEnd",
    "CameraMeasurement",
    "CameraSensor",
    "ClosedLoop",
    "ControllerContext",
    "ControllerFailure",
    "Disturbances",
    "Estimator",
    "GlobalView",
    "LocalView",
    "LoopStep",
    "LowLevelController",
    "Perception",
    "Plant",
    "PlantState",
    "RenderedFrontEnd",
    "RunResult",
    "SafetyMonitor",
    "SensorReadings",
    "Sensors",
    "Servo",
    "ServoCommand",
    "ServoEvent",
    "StateEstimate",
    "Termination",
    "VisualServo",
    "load_class",
    "normalized_rmse",
]
