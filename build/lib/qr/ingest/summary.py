"""Per-flight summary of an ingested log: what arrived, and how far the nominal model is off."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..dynamics import thrust_torque
from ..errors import QrInputError
from ..estimation.savgol import derivatives
from ..flight import POSITION, QUATERNION, ROTORS, dropouts, hover_ratio
from ..frames import GRAVITY, quat_to_rot, to_world


def flight_summary(df: pd.DataFrame, vehicle, name: str, source=None) -> dict:
    """Duration, rate, rows, dropouts, hover thrust ratio and the mean residual force (world frame).

    The residual uses Savitzky-Golay accelerations of the mocap position (21
    samples at 100 Hz, cubic) and raw rotor speeds: a pre-filter look, good for
    means, not for per-sample labels.  ``source``: the file, named in errors.
    """
    t = df["t"].to_numpy()
    _check_long_enough(df, source or df.attrs.get("source") or name)
    drop = dropouts(df)
    a_w = derivatives(t, df[POSITION].to_numpy(), order=2)
    q = df[QUATERNION].to_numpy()
    u = df[ROTORS].to_numpy()
    ok = np.isfinite(q).all(axis=1) & np.isfinite(u).all(axis=1)
    R = quat_to_rot(q[ok])
    T, _ = thrust_torque(u[ok], vehicle)
    thrust_w = to_world(R, np.column_stack([np.zeros_like(T), np.zeros_like(T), T]))
    f_w = vehicle.mass * (a_w[ok] - GRAVITY) - thrust_w
    mean_f = f_w.mean(axis=0)
    return {
        "flight": name,
        "vehicle": vehicle.name,
        "duration_s": float(t[-1] - t[0]),
        "rate_hz": float(1.0 / drop["median_dt"]),
        "rows": int(len(df)),
        "mocap_dropouts": drop["mocap_blank"],
        "rotor_dropouts": drop["rotor_blank"],
        "missed_frames": drop["missed_frames"],
        "hover_thrust_ratio": hover_ratio(df, vehicle),
        "mean_fa_world_x": float(mean_f[0]),
        "mean_fa_world_y": float(mean_f[1]),
        "mean_fa_world_z": float(mean_f[2]),
        "std_fa_world_z": float(f_w[:, 2].std()),
    }


def _check_long_enough(df, source):
    from ..estimation.savgol import uniform_grid, window

    t = df["t"].to_numpy()
    fix = "summarise a complete flight (seconds of samples), not a fragment"
    if len(t) < 2:
        raise QrInputError(source, f"flight has only {len(t)} sample: no rate, no accelerations", fix)
    n_pos = int(np.isfinite(df[POSITION].to_numpy()).all(axis=1).sum())
    need = window(uniform_grid(t))
    if len(uniform_grid(t)) < need or n_pos < need:
        raise QrInputError(source, f"flight has {len(t)} samples, {n_pos} with a position; the summary's "
                                   f"accelerations need at least {need} (a 0.21 s Savitzky-Golay window)", fix)
    ok = np.isfinite(df[QUATERNION].to_numpy()).all(axis=1) & np.isfinite(df[ROTORS].to_numpy()).all(axis=1)
    if not ok.any():
        raise QrInputError(source, "no sample has both an attitude and four rotor speeds",
                           "check the log: the summary's residual force needs both")
