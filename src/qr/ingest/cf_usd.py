"""Crazyflie uSD-card binary log (format version 2, as the data's SOURCE.md describes it: event types, then
records up to a trailing CRC32), as in ../shared/data/imrclab-crazyflie.

The canonical flight's rows are the motion-capture pose ``estPose`` with the 500 Hz block (``rpm``, gyro,
accelerometer, battery) interpolated onto them; ``read_fast`` gives the 500 Hz block itself in SI units with
the on-board estimate, the motor commands and the controller's log (``ctrlLee.*``) that ``qr replay`` reads.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import QrInputError
from ..frames import G
from . import resample

MAGIC = b"\xbc"
POSE_EVENT = "estPose"
FAST_EVENT = "fixedFrequency"
DEG = np.pi / 180.0


def _fail(path, problem, fix="copy the log again from the uSD card; a partial or damaged file cannot be trusted"):
    return QrInputError(path, problem, fix)


def decode(path: str | Path) -> dict[str, pd.DataFrame]:
    """All events of a log as DataFrames with a ``timestamp_us`` column, CRC-checked."""
    path = Path(path)
    data = path.read_bytes()
    if len(data) < 9 or data[:1] != MAGIC:
        raise _fail(path, "not a Crazyflie uSD log (magic byte 0xBC missing)",
                    "pass --format csv for a canonical CSV, or the raw uSD file")
    body, crc = data[:-4], data[-4:]
    if zlib.crc32(body) & 0xFFFFFFFF != struct.unpack("<I", crc)[0]:
        raise _fail(path, "CRC32 check failed: the log is truncated or corrupted")
    version, n_types = struct.unpack_from("<HH", body, 1)
    if version != 2:
        raise _fail(path, f"uSD log format version {version}, expected 2",
                    "convert it with the Crazyflie tools (cfusdlog) to the canonical CSV")
    pos = 5
    types = {}
    try:
        for _ in range(n_types):
            (eid,) = struct.unpack_from("<H", body, pos)
            pos += 2
            end = body.index(b"\0", pos)
            name = body[pos:end].decode()
            pos = end + 1
            (nvars,) = struct.unpack_from("<H", body, pos)
            pos += 2
            names, codes = [], ""
            for _ in range(nvars):
                end = body.index(b"\0", pos)
                var = body[pos:end].decode()
                pos = end + 1
                names.append(var[: var.index("(")])
                codes += var[var.index("(") + 1: var.index(")")]
            fmt = struct.Struct("<" + codes)
            types[eid] = (name, names, fmt)
    except (ValueError, struct.error, UnicodeDecodeError):
        raise _fail(path, "the log header cannot be decoded") from None

    rows = {eid: [] for eid in types}
    stamps = {eid: [] for eid in types}
    head = struct.Struct("<HQ")
    n = len(body)
    while pos < n:
        if pos + head.size > n:
            raise _fail(path, f"record header cut off at byte {pos}")
        eid, ts = head.unpack_from(body, pos)
        pos += head.size
        if eid not in types:
            raise _fail(path, f"unknown event id {eid} at byte {pos - head.size}")
        fmt = types[eid][2]
        if pos + fmt.size > n:
            raise _fail(path, f"record cut off at byte {pos}")
        rows[eid].append(fmt.unpack_from(body, pos))
        stamps[eid].append(ts)
        pos += fmt.size
    out = {}
    for eid, (name, names, _) in types.items():
        df = pd.DataFrame(rows[eid], columns=names, dtype="float64")
        df.insert(0, "timestamp_us", np.array(stamps[eid], dtype=np.int64))
        out[name] = df
    return out


def read(path: str | Path) -> pd.DataFrame:
    path = Path(path)
    events = decode(path)
    if POSE_EVENT not in events or FAST_EVENT not in events:
        raise _fail(path, f"log lacks the '{POSE_EVENT}' or '{FAST_EVENT}' event",
                    "log motion capture (on:estPose) and the 500 Hz block (on:fixedFrequency) in config.txt")
    pose = events[POSE_EVENT].drop_duplicates("timestamp_us", keep="last").sort_values("timestamp_us")
    fast = events[FAST_EVENT].drop_duplicates("timestamp_us", keep="last").sort_values("timestamp_us")
    if len(pose) < 2:
        raise _fail(path, "log holds fewer than two motion-capture poses",
                    "check that the mocap pose reached the vehicle during the flight")
    need = [f"rpm.m{i}" for i in range(1, 5)]
    if any(c not in fast for c in need):
        raise _fail(path, "log has no rotor speeds (rpm.m1..m4)", "fit the RPM deck and log rpm.m1..m4")
    t0 = pose["timestamp_us"].iloc[0]
    t = (pose["timestamp_us"].to_numpy() - t0) * 1e-6
    tf = (fast["timestamp_us"].to_numpy() - t0) * 1e-6

    def interp(col, scale=1.0):
        return resample.onto(t, tf, fast[col].to_numpy() * scale)

    df = pd.DataFrame({
        "t": t,
        "px": pose["locSrv.x"].to_numpy(), "py": pose["locSrv.y"].to_numpy(), "pz": pose["locSrv.z"].to_numpy(),
        "qw": pose["locSrv.qw"].to_numpy(), "qx": pose["locSrv.qx"].to_numpy(),
        "qy": pose["locSrv.qy"].to_numpy(), "qz": pose["locSrv.qz"].to_numpy(),
    })
    for i in range(1, 5):
        df[f"u{i}"] = interp(f"rpm.m{i}")
    if all(f"pwm.m{i}_pwm" in fast for i in range(1, 5)):  # the motor commands too, for a command vehicle
        for i in range(1, 5):
            df[f"cmd{i}"] = interp(f"pwm.m{i}_pwm", 1.0 / 65535)  # raw 16-bit command -> [0, 1]
    optional = {"ax": ("acc.x", G), "ay": ("acc.y", G), "az": ("acc.z", G),  # g -> m/s^2, specific force
                "gx": ("gyro.x", DEG), "gy": ("gyro.y", DEG), "gz": ("gyro.z", DEG),  # deg/s -> rad/s
                "vbat": ("pm.vbatMV", 1e-3)}  # mV -> V
    for col, (src, scale) in optional.items():
        if src in fast:
            df[col] = interp(src, scale)
    return df


# the 500 Hz block's variables in SI: name -> (source, scale); ctrlLee.* is kept as logged (SI already:
# rad, rad/s, N, N m), with its dots replaced by underscores
FAST_SI = {
    "px": ("stateEstimate.x", 1.0), "py": ("stateEstimate.y", 1.0), "pz": ("stateEstimate.z", 1.0),
    "vx": ("stateEstimate.vx", 1.0), "vy": ("stateEstimate.vy", 1.0), "vz": ("stateEstimate.vz", 1.0),
    "qw": ("stateEstimate.qw", 1.0), "qx": ("stateEstimate.qx", 1.0), "qy": ("stateEstimate.qy", 1.0),
    "qz": ("stateEstimate.qz", 1.0),
    "gx": ("gyro.x", DEG), "gy": ("gyro.y", DEG), "gz": ("gyro.z", DEG),  # deg/s -> rad/s
    "ax": ("acc.x", G), "ay": ("acc.y", G), "az": ("acc.z", G),  # g -> m/s², specific force
    "u1": ("rpm.m1", 1.0), "u2": ("rpm.m2", 1.0), "u3": ("rpm.m3", 1.0), "u4": ("rpm.m4", 1.0),
    "cmd1": ("pwm.m1_pwm", 1.0 / 65535), "cmd2": ("pwm.m2_pwm", 1.0 / 65535),  # raw 16-bit -> [0, 1]
    "cmd3": ("pwm.m3_pwm", 1.0 / 65535), "cmd4": ("pwm.m4_pwm", 1.0 / 65535),
    "vbat": ("pm.vbatMV", 1e-3),  # mV -> V
}


def read_fast(path: str | Path) -> pd.DataFrame:
    """The 500 Hz block (``fixedFrequency``) in SI on the canonical flight's clock (``t`` = 0 at the first
    motion-capture pose): the on-board estimate (``px..vz``, ``qw..qz``: position, velocity, attitude as the
    controller saw them), gyro, accelerometer, rotor speeds (rpm), motor commands (``cmd1..4`` in [0, 1]),
    battery, and every ``ctrlLee.*`` variable as ``ctrlLee_*`` (the Lee controller's references and
    outputs, where logged).  A variable the log lacks is left out."""
    path = Path(path)
    events = decode(path)
    if POSE_EVENT not in events or FAST_EVENT not in events:
        raise _fail(path, f"log lacks the '{POSE_EVENT}' or '{FAST_EVENT}' event",
                    "log motion capture (on:estPose) and the 500 Hz block (on:fixedFrequency) in config.txt")
    pose = events[POSE_EVENT]
    fast = events[FAST_EVENT].drop_duplicates("timestamp_us", keep="last").sort_values("timestamp_us")
    t0 = pose["timestamp_us"].min()
    out = {"t": (fast["timestamp_us"].to_numpy() - t0) * 1e-6}
    for col, (src, scale) in FAST_SI.items():
        if src in fast:
            out[col] = fast[src].to_numpy() * scale
    for src in fast.columns:
        if src.startswith("ctrlLee."):
            out[src.replace(".", "_")] = fast[src].to_numpy()
    return pd.DataFrame(out)
