"""What the replay reads of a flight: the logged pose and rotor speeds (the truth it compares with), and
where the log has them the motor commands, the on-board state estimate and the controller's own log (a
Crazyflie uSD log's 500 Hz block), or the setpoints and true initial state of a ``qr synth`` folder.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import QrInputError
from ..flight import POSITION, QUATERNION

COMMANDS = ["cmd1", "cmd2", "cmd3", "cmd4"]


@dataclass(frozen=True)
class ReplayLog:
    """One flight as the replay reads it: ``pose`` (the canonical flight: ``t``, position, attitude, rotor
    speeds, optional gyro and battery), ``fast`` (a Crazyflie uSD log's 500 Hz block, :func:`qr.ingest.
    cf_usd.read_fast`, or None), ``synth`` (a qr synth folder's ``truth.json`` and ``truth.parquet``, or None)."""

    path: str
    pose: pd.DataFrame
    fast: pd.DataFrame | None = None
    synth: dict | None = None
    truth: pd.DataFrame | None = None

    @property
    def name(self) -> str:
        return Path(self.path).name if Path(self.path).name != "flight.csv" else str(self.path)

    @property
    def has_commands(self) -> bool:
        return self.fast is not None and all(c in self.fast for c in COMMANDS)

    def vbat(self) -> float:
        """Mean battery voltage (V) while logged, else 0."""
        for df in (self.fast, self.pose):
            if df is not None and "vbat" in df and np.isfinite(df["vbat"]).any():
                return float(np.nanmean(df["vbat"].to_numpy(float)))
        return 0.0

    def controller_view(self):
        """(t, p, v, R, q, w): the state the vehicle's controller saw: the on-board estimate and gyro where
        logged, else the logged pose with Savitzky–Golay velocity and the attitude's rate."""
        from ..frames import quat_to_rot

        if self.fast is not None and all(c in self.fast for c in ("px", "vx", "qw", "gx")):
            f = self.fast
            t = f["t"].to_numpy(float)
            q = f[QUATERNION].to_numpy(float)
            return (t, f[POSITION].to_numpy(float), f[["vx", "vy", "vz"]].to_numpy(float), quat_to_rot(q), q,
                    f[["gx", "gy", "gz"]].to_numpy(float))
        t, p, v, q, w = pose_states(self.pose)
        return t, p, v, quat_to_rot(q), q, w


def pose_states(pose: pd.DataFrame):
    """(t, p, v, q, w) of a canonical flight: velocity by Savitzky–Golay derivative of the position, body
    rate from the gyro where logged, else from the attitude's derivative (``ω = 2 vec(q⁻¹ ⊗ q̇)``)."""
    from ..estimation.savgol import derivatives
    from ..frames import make_continuous, quat_multiply

    t = pose["t"].to_numpy(float)
    p = pose[POSITION].to_numpy(float)
    q = pose[QUATERNION].to_numpy(float)
    ok = np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1)
    if ok.sum() < 8:
        raise QrInputError(pose.attrs.get("source"), "fewer than 8 samples with a pose",
                           "give a flight with motion capture")
    qf = np.array([np.interp(t, t[ok], q[ok, i]) for i in range(4)]).T
    qf = make_continuous(qf / np.linalg.norm(qf, axis=1, keepdims=True))
    v = derivatives(t, p, 1)
    if all(c in pose for c in ("gx", "gy", "gz")) and np.isfinite(pose[["gx", "gy", "gz"]].to_numpy(float)).all():
        w = pose[["gx", "gy", "gz"]].to_numpy(float)
    else:
        qd = derivatives(t, qf, 1)
        conj = qf * np.array([1.0, -1.0, -1.0, -1.0])
        w = 2.0 * quat_multiply(conj, qd)[:, 1:]
    return t, p, v, qf, w


def read_replay_log(path, vehicle) -> ReplayLog:
    """The flight at ``path`` read for the replay (format found by content; ``vehicle``: the first file)."""
    from ..ingest import detect_format, read_log

    path = Path(path)
    if not path.exists():
        raise QrInputError(path, "flight file does not exist", "check the path")
    kind = "folder" if path.is_dir() else detect_format(path)
    if kind == "folder" and (path / "flight.csv").exists():
        raise QrInputError(path, "is a folder", f"give the flight file itself ({path / 'flight.csv'})")
    if kind == "cf-usd":
        from ..ingest.cf_usd import read_fast

        return ReplayLog(str(path), read_log(path, vehicle), read_fast(path))
    pose = read_log(path, vehicle)
    truth_json = path.parent / "truth.json"
    if kind == "csv" and truth_json.exists():
        try:
            synth = json.loads(truth_json.read_text())
        except (OSError, ValueError):
            synth = None
        if isinstance(synth, dict) and synth.get("schema") == "qr.synth/1" and "setpoints" in synth:
            truth = path.parent / "truth.parquet"
            return ReplayLog(str(path), pose, None, synth, pd.read_parquet(truth) if truth.exists() else None)
    return ReplayLog(str(path), pose)
