"""State estimation: proprioceptive sensors and an EKF on the controller's model.

* :mod:`.sensors`: drone pose, IMU and tendon-encoder models (seeded, with latency/dropout);
* :mod:`.ekf`: :class:`ExtendedKalmanFilter` (``reset``, ``step(t, u_applied, measurements) ->
  StateEstimate``);
* :mod:`.inversion`: strains from measured tendon lengths (least squares);
* :mod:`.camera`: the tip camera's view of the static target as a filter measurement;
* :mod:`.sensor_limits`: the hover errors a pose sensor and an IMU allow (sensor sizing);
* :mod:`.block`: :class:`FilterBlock`, the filter as the closed loop's estimation block
  (``estimation.source = "estimated"``, assembled by :func:`tdacm.sim.assemble.build_loop`).
"""

from .block import FilterBlock
from .camera import TargetCamera, TargetViewMeasurement
from .config import (
    EncoderConfig,
    EstimationConfig,
    ImuConfig,
    PoseSensorConfig,
    SensorSuiteConfig,
)
from .ekf import (
    EstimatorConfig,
    EstimatorDiverged,
    ExtendedKalmanFilter,
    StateEstimate,
    euler_from_rotation,
)
from .inversion import InversionResult, strains_from_tendon_lengths
from .proprioception import (
    DronePoseSensor,
    EncoderMeasurement,
    Imu,
    ImuMeasurement,
    PoseMeasurement,
    SensorSuite,
    TendonEncoders,
)
from .sensor_limits import HoverEstimateLimits, PinnedView, hover_estimate_limits

__all__ = [
    "EstimationConfig",
    "DronePoseSensor",
    "EncoderConfig",
    "EncoderMeasurement",
    "ExtendedKalmanFilter",
    "FilterBlock",
    "HoverEstimateLimits",
    "EstimatorConfig",
    "EstimatorDiverged",
    "Imu",
    "ImuConfig",
    "ImuMeasurement",
    "InversionResult",
    "PoseMeasurement",
    "PoseSensorConfig",
    "SensorSuite",
    "SensorSuiteConfig",
    "StateEstimate",
    "TargetCamera",
    "TargetViewMeasurement",
    "TendonEncoders",
    "euler_from_rotation",
    "hover_estimate_limits",
    "PinnedView",
    "strains_from_tendon_lengths",
]
