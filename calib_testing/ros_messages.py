"""ROS message definitions and packed sensor_msgs/Imu layouts, for writing test and benchmark logs.

The definitions are the concatenated ros2msg text with its dependencies, the way
``ros2 bag record`` stores them. `imu_cdr` and `imu_ros1` are numpy structured dtypes of one
Imu message, so that a block of messages is serialised with one ``tobytes()``.
"""

from __future__ import annotations

import numpy as np

SEP = "=" * 80 + "\n"
_DEPS_HEADER = (
    SEP + "MSG: std_msgs/Header\n"
    "# Standard metadata for higher-level stamped data types.\n"
    "builtin_interfaces/Time stamp\n"
    "string frame_id\n" + SEP + "MSG: builtin_interfaces/Time\n"
    "int32 sec\n"
    "uint32 nanosec\n"
)
IMU_MSGDEF = (
    "std_msgs/Header header\n"
    "geometry_msgs/Quaternion orientation\n"
    "float64[9] orientation_covariance # Row major about x, y, z axes\n"
    "geometry_msgs/Vector3 angular_velocity\n"
    "float64[9] angular_velocity_covariance # Row major about x, y, z axes\n"
    "geometry_msgs/Vector3 linear_acceleration\n"
    "float64[9] linear_acceleration_covariance # Row major x, y z\n"
    + _DEPS_HEADER
    + SEP
    + "MSG: geometry_msgs/Quaternion\n"
    "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n" + SEP + "MSG: geometry_msgs/Vector3\n"
    "float64 x\nfloat64 y\nfloat64 z\n"
)
TEMPERATURE_MSGDEF = (
    "std_msgs/Header header\n"
    "float64 temperature # Measurement of the Temperature in Degrees Celsius.\n"
    "float64 variance # 0 is interpreted as variance unknown.\n" + _DEPS_HEADER
)
JOINT_STATE_MSGDEF = (
    "std_msgs/Header header\n"
    "string[] name\n"
    "float64[] position\n"
    "float64[] velocity\n"
    "float64[] effort\n" + _DEPS_HEADER
)

# The 37 float64 of an Imu message after its Header, in ROS 1 and ROS 2 alike.
_IMU_BODY = [
    ("orientation", "<f8", 4),
    ("orientation_cov", "<f8", 9),
    ("gyr", "<f8", 3),
    ("gyr_cov", "<f8", 9),
    ("acc", "<f8", 3),
    ("acc_cov", "<f8", 9),
]


def imu_cdr(frame_id: bytes) -> np.dtype:
    """One little-endian CDR (ROS 2) Imu message with `frame_id`: the encapsulation, the Header
    (stamp, frame_id with its NUL, padding to 8 within the CDR body), then the 37 float64
    (pipelines.ingest.cdr). Set ``encapsulation`` to (0, 1, 0, 0) and ``frame_len``."""
    n = len(frame_id) + 1
    return np.dtype(
        [
            ("encapsulation", "u1", 4),
            ("sec", "<i4"),
            ("nanosec", "<u4"),
            ("frame_len", "<u4"),
            ("frame_id", f"S{n}"),
            ("pad", "u1", -(12 + n) % 8),
            *_IMU_BODY,
        ]
    )


def imu_ros1(frame_id: bytes) -> np.dtype:
    """One ROS 1 Imu message with `frame_id` (ROS 1 serialisation: packed, no NUL, no
    padding). Set ``frame_len``."""
    return np.dtype(
        [
            ("seq", "<u4"),
            ("sec", "<u4"),
            ("nsec", "<u4"),
            ("frame_len", "<u4"),
            ("frame_id", f"S{len(frame_id)}"),
            *_IMU_BODY,
        ]
    )
