"""Vision layer of the dual-camera servoing (paper, "Dual-Camera Servoing Algorithm").

Cameras (:mod:`.camera`, :mod:`.mounts`), targets and scene (:mod:`.targets`, :mod:`.scene`),
renderers behind one interface (:mod:`.render`), fiducial detection (:mod:`.detect`), the
virtual camera C_V (:mod:`.virtual`), the advanced features and their interaction matrix
(:mod:`.features`), the IBVS law (:mod:`.ibvs`), the tip-level mapping (:mod:`.tip`) and the
estimate of a static target from its detections (:mod:`.target_filter`). The servo that chains
them in the closed loop is :mod:`tdacm.loop.servo`. See ``docs/vision.md``.

Conventions: camera frames x right, y down, z forward; normalized coordinates
``x = X/Z, y = Y/Z``; twists angular-first ``[w; v]`` (as the model), except where a function
takes ``order="linear_first"``.
"""

from .camera import GLOBAL_CAMERA, LOCAL_CAMERA, PinholeCamera, world_to_camera
from .detect import NOT_DETECTED, Detection, TargetDetector, detect_target
from .features import (
    advanced_features,
    depth_from_size,
    estimate_depths,
    feature_error,
    feature_interaction_matrix,
    features_jacobian,
    paper_features,
    point_interaction_matrix,
    wrap_angle,
)
from .ibvs import IBVSController, ibvs_twist
from .mounts import (
    DEFAULT_DRONE_CAMERA_MOUNT,
    DEFAULT_TIP_CAMERA_MOUNT,
    camera_pose,
    drone_camera_mount,
    tip_camera_mount,
    tip_camera_pose,
)
from .render import PlanarRenderer, PyBulletRenderer, Renderer
from .scene import ArmStyle, SceneConfig
from .target_filter import TargetEstimate, TargetFilter, reference_from_pose
from .targets import PAPER_MARKER, PAPER_PATTERN, AprilTagPattern, ArucoMarker, FiducialTarget
from .tip import camera_joint_rates, camera_to_tip_twist, commanded_coordinates, tip_joint_rates
from .virtual import (
    virtual_camera_points,
    virtual_camera_pose,
    virtual_camera_transform,
    yaw_only_pose,
)

__all__ = [
    "DEFAULT_DRONE_CAMERA_MOUNT",
    "DEFAULT_TIP_CAMERA_MOUNT",
    "GLOBAL_CAMERA",
    "LOCAL_CAMERA",
    "NOT_DETECTED",
    "PAPER_MARKER",
    "PAPER_PATTERN",
    "AprilTagPattern",
    "ArmStyle",
    "ArucoMarker",
    "Detection",
    "FiducialTarget",
    "IBVSController",
    "TargetEstimate",
    "TargetFilter",
    "PinholeCamera",
    "PlanarRenderer",
    "PyBulletRenderer",
    "Renderer",
    "SceneConfig",
    "TargetDetector",
    "advanced_features",
    "camera_joint_rates",
    "camera_pose",
    "camera_to_tip_twist",
    "commanded_coordinates",
    "depth_from_size",
    "detect_target",
    "drone_camera_mount",
    "estimate_depths",
    "feature_error",
    "feature_interaction_matrix",
    "features_jacobian",
    "ibvs_twist",
    "paper_features",
    "point_interaction_matrix",
    "reference_from_pose",
    "tip_camera_mount",
    "tip_camera_pose",
    "tip_joint_rates",
    "virtual_camera_points",
    "virtual_camera_pose",
    "virtual_camera_transform",
    "world_to_camera",
    "wrap_angle",
    "yaw_only_pose",
]
