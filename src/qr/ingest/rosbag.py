"""ROS 1 bags and ROS 2 bags (sqlite3 or MCAP) with ``rosbags``: topics chosen by message type
(pose, rotor speeds, IMU; ``--topic KIND=/name`` chooses among several), in ROS's frames (REP 103), which are
qr's own.  Every stream stamped by its header and interpolated onto the pose stamps.  The message types
read: docs/ingest.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import QrInputError
from ..frames import make_continuous
from . import resample

POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry")
ROTOR_TYPES = ("mav_msgs/msg/Actuators",)
ARRAY_TYPES = ("std_msgs/msg/Float64MultiArray", "std_msgs/msg/Float32MultiArray")
IMU_TYPES = ("sensor_msgs/msg/Imu",)
KINDS = ("pose", "rotors", "imu")
ACTUATORS_MSG = """std_msgs/Header header
float64[] angles
float64[] angular_velocities
float64[] normalized
"""


def typestore():
    """ROS 2's standard messages plus ``mav_msgs/msg/Actuators``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(ACTUATORS_MSG, "mav_msgs/msg/Actuators"))
    return store


def _normal(msgtype: str) -> str:
    """ROS 1 names types ``pkg/Name``, ROS 2 ``pkg/msg/Name``."""
    pkg, _, name = msgtype.rpartition("/")
    return msgtype if pkg.endswith("/msg") else f"{pkg}/msg/{name}"


def _stamp_ns(msg, received: int) -> int:
    header = getattr(msg, "header", None)
    if header is None:
        return int(received)
    st = header.stamp
    return int(st.sec) * 1_000_000_000 + int(getattr(st, "nanosec", getattr(st, "nsec", 0)))


def parse_topics(items) -> dict:
    """``["pose=/a", "rotors=/b"]`` (the ``--topic`` flags) as ``{"pose": "/a", "rotors": "/b"}``."""
    out = {}
    for item in items or ():
        kind, sep, name = str(item).partition("=")
        if not sep or kind not in KINDS or not name:
            raise QrInputError("--topic", f"{item!r} is not KIND=/topic with KIND one of {', '.join(KINDS)}",
                               "write e.g. --topic pose=/vicon/quad/pose")
        out[kind] = name
    return out


def read(path: str | Path, topics: dict | None = None) -> pd.DataFrame:
    from rosbags.highlevel import AnyReader

    path, topics = Path(path), dict(topics or {})
    try:
        reader = AnyReader([path], default_typestore=typestore())
        reader.open()
    except Exception as e:  # rosbags raises its own errors for damaged or unknown files
        raise QrInputError(path, f"not a readable ROS bag ({type(e).__name__}: {e})",
                           "give a ROS 1 .bag file or a ROS 2 bag folder (metadata.yaml with .db3 or .mcap)") from None
    try:
        return _read(reader, path, topics)
    except QrInputError:
        raise
    except Exception as e:  # a damaged message: rosbags' deserialisers raise whatever the bytes cause
        raise QrInputError(path, f"damaged ROS bag ({type(e).__name__}: {e})",
                           "record or copy the bag again; a cut or corrupted bag cannot be trusted") from None
    finally:
        reader.close()


def _choose(conns: dict, topics: dict, path: Path, kind: str, types: tuple, required: bool = True):
    """The connection of ``kind`` (pose, rotors, imu): the topic named by ``--topic``, else the one topic of
    one of ``types`` with messages."""
    have = ", ".join(f"{t} ({_normal(c.msgtype)})" for t, c in sorted(conns.items())) or "none"
    if kind in topics:
        c = conns.get(topics[kind])
        if c is None:
            raise QrInputError(path, f"--topic {kind}={topics[kind]}: no such topic (the bag has: {have})",
                               "name one of the bag's topics")
        return c
    found = [c for c in conns.values() if _normal(c.msgtype) in types and c.msgcount > 0]
    if len(found) > 1:
        raise QrInputError(path, f"several {kind} topics ({', '.join(c.topic for c in found)})",
                           f"choose one with --topic {kind}=/name")
    if not found and required:
        raise QrInputError(path, f"no {kind} topic ({' or '.join(t.replace('/msg/', '/') for t in types)}; "
                                 f"the bag has: {have})", f"record one, or name it with --topic {kind}=/name")
    return found[0] if found else None


def _messages(reader, conn):
    for c, received, raw in reader.messages(connections=[conn]):
        yield reader.deserialize(raw, c.msgtype), received


def _pose_table(reader, pose_c, path: Path) -> tuple[pd.DataFrame, np.ndarray, int]:
    """The poses in time order (a repeated stamp: the first message stands), t from the first pose; the
    table, its stamps (ns from the first) and the first stamp (ns)."""
    rows = []
    for msg, rec in _messages(reader, pose_c):
        pose = msg.pose.pose if _normal(pose_c.msgtype) == "nav_msgs/msg/Odometry" else msg.pose
        p, o = pose.position, pose.orientation
        rows.append((_stamp_ns(msg, rec), p.x, p.y, p.z, o.w, o.x, o.y, o.z))
    if len(rows) < 2:
        raise QrInputError(path, f"topic {pose_c.topic} holds fewer than two poses", "record the flight's pose")
    rows.sort(key=lambda r: r[0])
    t0 = rows[0][0]
    pose = np.array([(r[0] - t0, *r[1:]) for r in rows], dtype=float)  # ns from the first pose (exact in int)
    keep = np.concatenate([[True], np.diff(pose[:, 0]) > 0])
    pose = pose[keep]
    t_ns = pose[:, 0]
    q = make_continuous(pose[:, 4:8])
    df = pd.DataFrame({"t": t_ns * 1e-9, "px": pose[:, 1], "py": pose[:, 2], "pz": pose[:, 3],
                       "qw": q[:, 0], "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3]})
    return df, t_ns, t0


def _read(reader, path: Path, topics: dict) -> pd.DataFrame:
    conns = {c.topic: c for c in reader.connections}
    pose_c = _choose(conns, topics, path, "pose", POSE_TYPES)
    rotor_c = _choose(conns, topics, path, "rotors", ROTOR_TYPES + (ARRAY_TYPES if "rotors" in topics else ()))
    imu_c = _choose(conns, topics, path, "imu", IMU_TYPES, required=False)
    df, t_ns, t0 = _pose_table(reader, pose_c, path)

    def onto(stamps, values):
        return resample.onto(t_ns, np.array([s - t0 for s in stamps], dtype=float), values)

    stamps, speeds = [], []
    for msg, rec in _messages(reader, rotor_c):
        vals = np.asarray(msg.data if _normal(rotor_c.msgtype) in ARRAY_TYPES else msg.angular_velocities, float)
        if vals.size < 4:
            raise QrInputError(path, f"topic {rotor_c.topic} holds {vals.size} rotor speeds, not 4",
                               "record all four rotor speeds")
        stamps.append(_stamp_ns(msg, rec))
        speeds.append(vals[:4])
    if len(stamps) < 2:
        raise QrInputError(path, f"topic {rotor_c.topic} holds fewer than two rotor-speed messages",
                           "record the rotor speeds through the flight")
    speeds = np.array(speeds)
    for i in range(4):
        df[f"u{i + 1}"] = onto(stamps, speeds[:, i])
    sources = {"pose": pose_c.topic, "rotors": rotor_c.topic}
    if imu_c is not None:
        st, vals = [], []
        for msg, rec in _messages(reader, imu_c):
            w, a = msg.angular_velocity, msg.linear_acceleration
            st.append(_stamp_ns(msg, rec))
            vals.append((w.x, w.y, w.z, a.x, a.y, a.z))
        vals = np.array(vals)
        for j, col in enumerate(["gx", "gy", "gz", "ax", "ay", "az"]):
            df[col] = onto(st, vals[:, j])
        sources["imu"] = imu_c.topic
    df.attrs["sources"] = sources
    df.attrs["rotor_unit"] = "rad_s"
    return df
