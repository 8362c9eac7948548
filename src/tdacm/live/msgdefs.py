"""ROS 2 message definitions embedded as MCAP schemas (encoding ``ros2msg``).

A ROS 2 MCAP file carries, for each message type, its ``.msg`` text followed by the definitions
of every type it uses, each introduced by a line of 80 ``=`` and ``MSG: pkg/msg/Type`` (the
layout ``ros2 bag record`` writes). The texts below are the fields of the ROS 2 (Humble and
later) interfaces, without comments and constants, in the same order: the CDR bytes depend on
that order, so a recording written with them plays back with ``ros2 bag play``.
"""

from __future__ import annotations

#: ``pkg/msg/Type`` -> its fields (ROS 2 ``.msg`` syntax).
DEFINITIONS = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/msg/Float64": "float64 data\n",
    "std_msgs/msg/MultiArrayDimension": "string label\nuint32 size\nuint32 stride\n",
    "std_msgs/msg/MultiArrayLayout": "MultiArrayDimension[] dim\nuint32 data_offset\n",
    "std_msgs/msg/Float64MultiArray": "MultiArrayLayout layout\nfloat64[] data\n",
    "geometry_msgs/msg/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/msg/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/msg/PoseStamped": "std_msgs/Header header\nPose pose\n",
    "geometry_msgs/msg/Transform": "Vector3 translation\nQuaternion rotation\n",
    "geometry_msgs/msg/TransformStamped": (
        "std_msgs/Header header\nstring child_frame_id\nTransform transform\n"
    ),
    "tf2_msgs/msg/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "sensor_msgs/msg/JointState": (
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
        "float64[] effort\n"
    ),
    "sensor_msgs/msg/RegionOfInterest": (
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n"
    ),
    "sensor_msgs/msg/CameraInfo": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n"
        "float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n"
        "uint32 binning_y\nRegionOfInterest roi\n"
    ),
    "sensor_msgs/msg/Image": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n"
        "uint8 is_bigendian\nuint32 step\nuint8[] data\n"
    ),
    "builtin_interfaces/msg/Duration": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/ColorRGBA": "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n",
    "visualization_msgs/msg/ImageMarker": (
        "std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\n"
        "geometry_msgs/Point position\nfloat32 scale\nstd_msgs/ColorRGBA outline_color\n"
        "uint8 filled\nstd_msgs/ColorRGBA fill_color\nbuiltin_interfaces/Duration lifetime\n"
        "geometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] outline_colors\n"
    ),
}

_PRIMITIVES = {
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
}  # fmt: skip


def _dependencies(name: str) -> list[str]:
    """The message types ``name`` uses, depth first, each once (``pkg/msg/Type``)."""
    pkg = name.split("/")[0]
    out: list[str] = []

    def visit(n: str, pkg: str):
        for line in DEFINITIONS[n].splitlines():
            ftype = line.split()[0].split("[")[0]
            if ftype in _PRIMITIVES:
                continue
            p, _, t = ftype.rpartition("/")
            full = f"{p or pkg}/msg/{t}"
            if full not in out:
                out.append(full)
                visit(full, full.split("/")[0])

    visit(name, pkg)
    return out


def schema_text(name: str) -> str:
    """The MCAP schema text of ``name`` (``pkg/msg/Type``): its fields, then every type it
    uses after a separator line and ``MSG: pkg/msg/Type``."""
    if name not in DEFINITIONS:
        raise KeyError(f"no ROS 2 definition for {name!r} (known: {', '.join(DEFINITIONS)})")
    parts = [DEFINITIONS[name]]
    for dep in _dependencies(name):
        parts.append("=" * 80 + f"\nMSG: {dep}\n" + DEFINITIONS[dep])
    return "".join(parts)
