"""A canonical flight written as a ROS bag with ``rosbags``' own writers (ROS 1, ROS 2 sqlite3 / MCAP).

Pose as ``geometry_msgs/PoseStamped`` (or ``nav_msgs/Odometry``), rotor speeds as ``mav_msgs/Actuators``
(rad/s), the gyro and accelerometer columns (if any) as ``sensor_msgs/Imu``; every message stamped by its
header, received ``lag_ns`` later.  Independent of ``qr.ingest.rosbag`` except for the message definition
of ``mav_msgs/Actuators``, which is ROS's own text.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

ACTUATORS = """std_msgs/Header header
float64[] angles
float64[] angular_velocities
float64[] normalized
"""


def _store(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(ACTUATORS, "mav_msgs/msg/Actuators"))
    return store


def write_bag(flight: pd.DataFrame, path: Path, kind: str = "sqlite3", rpm_to_rad_s: float = 1.0,
              odometry: bool = False, t0_ns: int = 1_700_000_000_000_000_000, lag_ns: int = 2_000_000,
              extra_pose_topic: str | None = None, rotors: bool = True) -> Path:
    """``kind``: ``sqlite3``, ``mcap`` (ROS 2 folders) or ``ros1`` (a .bag file).  Rotor speeds are
    multiplied by ``rpm_to_rad_s`` (bags carry rad/s)."""
    ros1 = kind == "ros1"
    store = _store(ros1)
    T = store.types
    if ros1:
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), store.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), store.serialize_cdr
    pose_type = "nav_msgs/msg/Odometry" if odometry else "geometry_msgs/msg/PoseStamped"
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Point, Quat, Vec = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Vector3"]
    Pose = T["geometry_msgs/msg/Pose"]

    def header(k, stamp):
        sec, nsec = divmod(stamp, 1_000_000_000)
        t = Time(sec=int(sec), nanosec=int(nsec))
        return Header(seq=k, stamp=t, frame_id="world") if ros1 else Header(stamp=t, frame_id="world")

    with writer:
        topics = ["/mocap/pose"] + ([extra_pose_topic] if extra_pose_topic else [])
        pose_conns = [writer.add_connection(t, pose_type, typestore=store) for t in topics]
        rotor = writer.add_connection("/motor_speed", "mav_msgs/msg/Actuators", typestore=store) if rotors else None
        has_imu = all(c in flight for c in ("gx", "gy", "gz", "ax", "ay", "az"))
        imu = writer.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store) if has_imu else None
        for k, row in enumerate(flight.itertuples(index=False)):
            stamp = t0_ns + int(round(row.t * 1e9))
            h = header(k, stamp)
            pose = Pose(position=Point(x=row.px, y=row.py, z=row.pz),
                        orientation=Quat(x=row.qx, y=row.qy, z=row.qz, w=row.qw))
            if odometry:
                cov = np.zeros(36)
                msg = T[pose_type](header=h, child_frame_id="body",
                                   pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
                                   twist=T["geometry_msgs/msg/TwistWithCovariance"](
                                       twist=T["geometry_msgs/msg/Twist"](linear=Vec(x=0.0, y=0.0, z=0.0),
                                                                          angular=Vec(x=0.0, y=0.0, z=0.0)),
                                       covariance=cov))
            else:
                msg = T[pose_type](header=h, pose=pose)
            if np.isfinite([row.px, row.qw]).all():
                for c in pose_conns:
                    writer.write(c, stamp + lag_ns, bytes(serialize(msg, pose_type)))
            if rotor is not None:
                speeds = np.array([row.u1, row.u2, row.u3, row.u4]) * rpm_to_rad_s
                act = T["mav_msgs/msg/Actuators"](header=h, angles=np.zeros(0), angular_velocities=speeds,
                                                  normalized=np.zeros(0))
                writer.write(rotor, stamp + lag_ns, bytes(serialize(act, "mav_msgs/msg/Actuators")))
            if imu is not None:
                z9 = np.zeros(9)
                m = T["sensor_msgs/msg/Imu"](header=h, orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0),
                                             orientation_covariance=z9,
                                             angular_velocity=Vec(x=row.gx, y=row.gy, z=row.gz),
                                             angular_velocity_covariance=z9,
                                             linear_acceleration=Vec(x=row.ax, y=row.ay, z=row.az),
                                             linear_acceleration_covariance=z9)
                writer.write(imu, stamp + lag_ns, bytes(serialize(m, "sensor_msgs/msg/Imu")))
    return path
