"""PX4 ULog (``pyulog``): a PX4 flight in the canonical frames and units.

The topics read (pose, rotor speeds or normalised motor commands, IMU, battery) and their order of preference:
docs/ingest.md.  PX4 is NED world / FRD body (:func:`qr.frames.from_ned_frd` converts); stamps are the pose
stream's, the other streams interpolated onto them; ``attrs["sources"]`` names the topics used and
``attrs["rotor_input"]`` is ``"speed"`` or ``"command"``.
"""

from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import QrInputError
from ..frames import frd_to_flu, from_ned_frd
from . import resample

POSE_TOPICS = ("vehicle_mocap_odometry", "vehicle_visual_odometry")


class _ReadsTooMuch(Exception):
    pass


class _Bounded:
    """The file as pyulog reads it, stopped once it has read several times the file's size: at a message cut
    short by the file's end pyulog seeks back by the message's full length, before where it began, and reads
    the same bytes again for ever (pyulog 1.3; a log copied off the SD card in part)."""

    def __init__(self, f, size: int):
        self._f, self._left = f, 4 * size + (1 << 20)

    def read(self, n: int = -1) -> bytes:
        data = self._f.read(n)
        self._left -= len(data)
        if self._left < 0:
            raise _ReadsTooMuch("the parser read the file's bytes over and over (a message cut short)")
        return data

    def seek(self, *args):
        return self._f.seek(*args)

    def tell(self) -> int:
        return self._f.tell()

    def close(self) -> None:  # the caller's `with` closes the file
        pass


class _Log:
    def __init__(self, path: Path):
        from pyulog import ULog

        try:
            with open(path, "rb") as f, contextlib.redirect_stdout(io.StringIO()):  # pyulog prints its warnings
                self.ulog = ULog(_Bounded(f, os.fstat(f.fileno()).st_size))
        except Exception as e:  # pyulog raises bare exceptions on a damaged file
            raise QrInputError(path, f"not a readable PX4 ULog ({type(e).__name__}: {e})",
                               "copy the .ulg again from the SD card; a partial file cannot be read") from None
        self.path = path
        self.params = self.ulog.initial_parameters

    def topics(self) -> list[str]:
        return sorted({d.name for d in self.ulog.data_list})

    def topic(self, name: str, fields: list[str]) -> dict | None:
        """The first instance of ``name`` holding every field (None if none does)."""
        for d in sorted(self.ulog.data_list, key=lambda d: d.multi_id):
            if d.name == name and all(f in d.data for f in fields) and len(d.data["timestamp"]) >= 2:
                return d.data
        return None

    def missing(self, what: str, fix: str):
        return QrInputError(self.path, f"the log has no {what} (its topics: {', '.join(self.topics())})", fix)


def _stamps(d: dict) -> np.ndarray:
    return np.asarray(d.get("timestamp_sample", d["timestamp"]), dtype=np.int64)


def _pose(log: _Log) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """Stamps (µs), NED positions (N, 3), FRD → NED quaternions (N, 4) and the source's name."""
    from scipy.spatial.transform import Rotation, Slerp

    q_fields = [f"q[{i}]" for i in range(4)]
    for name in POSE_TOPICS:
        for pos in (["position[0]", "position[1]", "position[2]"], ["x", "y", "z"]):
            d = log.topic(name, pos + q_fields)
            if d is not None:
                return (_stamps(d), np.column_stack([d[f] for f in pos]), np.column_stack([d[f] for f in q_fields]),
                        name)
    lp = log.topic("vehicle_local_position", ["x", "y", "z"])
    att = log.topic("vehicle_attitude", q_fields)
    if lp is None or att is None:
        raise log.missing("pose (vehicle_mocap_odometry, vehicle_visual_odometry, or vehicle_local_position "
                          "with vehicle_attitude)", "log the position and attitude topics (SDLOG_PROFILE)")
    t, ta = _stamps(lp), _stamps(att)
    qa = np.column_stack([att[f] for f in q_fields]).astype(float)  # float32 in the log: a corrupt one overflows
    ok = np.all(np.isfinite(qa), axis=1) & (np.linalg.norm(qa, axis=1) > 0.5)
    ta, qa = ta[ok], qa[ok]
    order = np.unique(ta, return_index=True)[1]
    ta, qa = ta[order], qa[order]
    q = np.full((len(t), 4), np.nan)
    inside = (t >= ta[0]) & (t <= ta[-1])
    if inside.any() and len(ta) >= 2:
        slerp = Slerp(ta.astype(float), Rotation.from_quat(qa, scalar_first=True))
        q[inside] = slerp(t[inside].astype(float)).as_quat(scalar_first=True)
    p = np.column_stack([lp["x"], lp["y"], lp["z"]]).astype(float)
    # EKF2 marks a position it has no fix for (no GPS, vision or mocap) invalid and logs 0: a dropout
    for cols, flag in (([0, 1], "xy_valid"), ([2], "z_valid")):
        if flag in lp:
            p[np.ix_(np.asarray(lp[flag]) == 0, cols)] = np.nan
    return t, p, q, "vehicle_local_position + vehicle_attitude"


# PX4's arming states (vehicle_status.arming_state): ARMED is 2 in every version (INIT 0 / STANDBY 1 before)
ARMED = 2


def _ever_armed(log: _Log) -> bool | None:
    """Whether the vehicle was armed at any time of the log (None: the log does not say)."""
    d = log.topic("actuator_armed", ["armed"])
    if d is not None:
        return bool(np.any(np.asarray(d["armed"]) == 1))
    d = log.topic("vehicle_status", ["arming_state"])
    if d is not None:
        return bool(np.any(np.asarray(d["arming_state"]) == ARMED))
    return None


def _pwm_range(log: _Log, i: int) -> tuple[float, float]:
    lo, hi = log.params.get(f"PWM_MAIN_MIN{i + 1}", -1), log.params.get(f"PWM_MAIN_MAX{i + 1}", -1)
    lo = lo if lo is not None and lo >= 0 else log.params.get("PWM_MIN", 1000)
    hi = hi if hi is not None and hi >= 0 else log.params.get("PWM_MAX", 2000)
    return float(lo), float(hi)


def _rotors(log: _Log) -> tuple[list[np.ndarray], np.ndarray, str, str]:
    """Per-motor signals, their stamps (µs), ``"speed"`` or ``"command"`` and the source's name."""
    rpm = [f"esc[{i}].esc_rpm" for i in range(4)]
    d = log.topic("esc_status", rpm)
    if d is not None:
        return [np.asarray(d[f], float) for f in rpm], _stamps(d), "speed", "esc_status (rpm)"
    d = log.topic("actuator_motors", [f"control[{i}]" for i in range(4)])
    if d is not None:
        return [np.asarray(d[f"control[{i}]"], float) for i in range(4)], _stamps(d), "command", "actuator_motors"
    d = log.topic("actuator_outputs", [f"output[{i}]" for i in range(4)])
    if d is not None:
        sig = []
        for i in range(4):
            lo, hi = _pwm_range(log, i)
            sig.append(np.clip((np.asarray(d[f"output[{i}]"], float) - lo) / (hi - lo), 0.0, 1.0))
        return sig, _stamps(d), "command", "actuator_outputs (PWM scaled by PWM_MIN/PWM_MAX)"
    raise log.missing("rotor signal (esc_status, actuator_motors or actuator_outputs)",
                      "log esc_status (ESC telemetry) or the actuator outputs")


def read(path: str | Path, check: bool = True) -> pd.DataFrame:
    """The log as a canonical flight; ``check``: refuse a log that holds no flight (never armed, no valid
    position), which a reader test of the frames may skip."""
    path = Path(path)
    log = _Log(path)
    df = _read(log)
    if check:
        if _ever_armed(log) is False:
            raise QrInputError(path, "the vehicle was never armed in this log (PX4 logs it disarmed throughout: "
                                     "the motors never ran)", "give the log of a flight")
        pos = df[["px", "py", "pz"]].to_numpy()
        if not np.isfinite(pos).all(axis=1).any():
            raise QrInputError(path, f"no valid position in the whole log ({df.attrs['sources']['pose']}: PX4 marks "
                                     "it invalid, e.g. xy_valid = 0 without GPS, vision or motion capture)",
                               "log a position source (motion capture or vision: vehicle_mocap_odometry / "
                               "vehicle_visual_odometry) or give a flight with a position fix")
    return df


def _read(log: _Log) -> pd.DataFrame:
    t_us, p_ned, q_ned, pose_src = _pose(log)
    keep = np.concatenate([[True], np.diff(t_us) != 0])  # repeated stamps: the first sample stands
    t_us, p_ned, q_ned = t_us[keep], p_ned[keep], q_ned[keep]
    back = np.flatnonzero(np.diff(t_us) < 0)
    if back.size:  # PX4 stamps each topic from one monotonic clock: a stamp that goes back is damage
        i = back[0] + 1
        raise QrInputError(log.path, f"the {pose_src} timestamps go back at sample {i} (from "
                                     f"{t_us[i - 1] * 1e-6:.6g} s to {t_us[i] * 1e-6:.6g} s): the log is damaged",
                           "copy the log from the vehicle again, or give a flight whose stamps only increase")
    t0 = t_us[0]
    t = (t_us - t0) * 1e-6

    def onto(ts_us, values):
        return resample.onto(t, (np.asarray(ts_us, np.int64) - t0) * 1e-6, values)

    p, q = from_ned_frd(p_ned, q_ned)
    df = pd.DataFrame({"t": t, "px": p[:, 0], "py": p[:, 1], "pz": p[:, 2],
                       "qw": q[:, 0], "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3]})
    signals, ts, kind, rotor_src = _rotors(log)
    for i, sig in enumerate(signals):
        df[f"u{i + 1}"] = onto(ts, sig)
    sources = {"pose": pose_src, "rotors": rotor_src}
    imu = log.topic("sensor_combined", [f"gyro_rad[{i}]" for i in range(3)] + [f"accelerometer_m_s2[{i}]" for i in range(3)])
    if imu is not None:
        ts = np.asarray(imu["timestamp"], np.int64)
        g = frd_to_flu(np.column_stack([imu[f"gyro_rad[{i}]"] for i in range(3)]))
        a = frd_to_flu(np.column_stack([imu[f"accelerometer_m_s2[{i}]"] for i in range(3)]))
        for j, ax in enumerate("xyz"):
            df[f"g{ax}"] = onto(ts, g[:, j])
            df[f"a{ax}"] = onto(ts, a[:, j])
        sources["imu"] = "sensor_combined"
    bat = log.topic("battery_status", ["voltage_v"])
    if bat is not None:
        df["vbat"] = onto(np.asarray(bat["timestamp"], np.int64), bat["voltage_v"])
        sources["vbat"] = "battery_status"
    df.attrs["sources"] = sources
    df.attrs["rotor_input"] = kind
    return df
