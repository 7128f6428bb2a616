"""ROS 2 message definitions (the `.msg` text, with dependencies) for reading and writing MCAP captures
with mcap-ros2-support, so no ROS install is needed. Field layouts are those of ROS 2 Humble onwards."""

from __future__ import annotations

_SEP = "=" * 80

_TIME = """int32 sec
uint32 nanosec"""

_HEADER = """builtin_interfaces/Time stamp
string frame_id"""

_DEPS: dict[str, str] = {
    "std_msgs/Header": _HEADER,
    "builtin_interfaces/Time": _TIME,
    "sensor_msgs/RegionOfInterest": """uint32 x_offset
uint32 y_offset
uint32 height
uint32 width
bool do_rectify""",
    "geometry_msgs/Quaternion": """float64 x 0
float64 y 0
float64 z 0
float64 w 1""",
    "geometry_msgs/Vector3": """float64 x
float64 y
float64 z""",
    "geometry_msgs/Point": """float64 x
float64 y
float64 z""",
    "geometry_msgs/Pose": """Point position
Quaternion orientation""",
}

_MAIN: dict[str, tuple[str, list[str]]] = {
    "sensor_msgs/msg/Image": (
        """std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data""",
        ["std_msgs/Header", "builtin_interfaces/Time"],
    ),
    "sensor_msgs/msg/CompressedImage": (
        """std_msgs/Header header
string format
uint8[] data""",
        ["std_msgs/Header", "builtin_interfaces/Time"],
    ),
    "sensor_msgs/msg/CameraInfo": (
        """std_msgs/Header header
uint32 height
uint32 width
string distortion_model
float64[] d
float64[9] k
float64[9] r
float64[12] p
uint32 binning_x
uint32 binning_y
RegionOfInterest roi""",
        ["std_msgs/Header", "builtin_interfaces/Time", "sensor_msgs/RegionOfInterest"],
    ),
    "sensor_msgs/msg/Imu": (
        """std_msgs/Header header
geometry_msgs/Quaternion orientation
float64[9] orientation_covariance
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance""",
        ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Quaternion", "geometry_msgs/Vector3"],
    ),
    "geometry_msgs/msg/PoseStamped": (
        """std_msgs/Header header
Pose pose""",
        [
            "std_msgs/Header",
            "builtin_interfaces/Time",
            "geometry_msgs/Pose",
            "geometry_msgs/Point",
            "geometry_msgs/Quaternion",
        ],
    ),
}

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMU = "sensor_msgs/msg/Imu"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"


def definition(datatype: str) -> str:
    """The full message definition text for `datatype` (e.g. "sensor_msgs/msg/Image"), as MCAP's
    ros2msg schema encoding expects: the type's fields, then each dependency after a separator line."""
    body, deps = _MAIN[datatype]
    parts = [body]
    for dep in deps:
        parts.append(f"{_SEP}\nMSG: {dep}\n{_DEPS[dep]}")
    return "\n".join(parts)


def header(t_ns: int, frame_id: str) -> dict:
    """A std_msgs/Header as the dict mcap-ros2-support writes."""
    return {"stamp": {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}, "frame_id": frame_id}


def stamp_ns(msg_header: object) -> int:
    """Nanoseconds since the epoch from a decoded std_msgs/Header."""
    stamp = msg_header.stamp  # type: ignore[attr-defined]
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
