"""The state table: what the filters write and everything downstream reads.

One row per sample of the tracked point (the log's body origin), Parquet
between stages.  ``qr synth``'s ``truth.parquet`` has the same columns, so
truth and estimates are interchangeable in tests.

| columns | meaning | frame, unit |
|---|---|---|
| t | time | s |
| px py pz, vx vy vz, ax ay az | position, velocity, acceleration | world, SI |
| qw qx qy qz | attitude, body -> world, scalar first | - |
| wx wy wz, alx aly alz | angular velocity, angular acceleration | body, rad/s, rad/s^2 |
| u1..u4, ud1..ud4 | rotor speeds and their rates | vehicle unit, unit/s |

Filters may add posterior standard deviations ``sd_<column>`` (same units)
and keep extra columns; readers ignore what they do not know.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .effects import Signals
from .frames import quat_to_rot, to_body

if TYPE_CHECKING:  # (annotations only)
    import pandas as pd

POSITION = ["px", "py", "pz"]
VELOCITY = ["vx", "vy", "vz"]
ACCELERATION = ["ax", "ay", "az"]
QUATERNION = ["qw", "qx", "qy", "qz"]
RATE = ["wx", "wy", "wz"]
ANGULAR_ACCELERATION = ["alx", "aly", "alz"]
ROTORS = ["u1", "u2", "u3", "u4"]
ROTOR_RATES = ["ud1", "ud2", "ud3", "ud4"]
# optional: squared rotor speeds smoothed like the position / attitude estimates, and rates
U2_FORCE = ["u2f1", "u2f2", "u2f3", "u2f4"]
U2_FORCE_RATE = ["u2fd1", "u2fd2", "u2fd3", "u2fd4"]
U2_TORQUE = ["u2t1", "u2t2", "u2t3", "u2t4"]
U2_TORQUE_RATE = ["u2td1", "u2td2", "u2td3", "u2td4"]
COLUMNS = ["t", *POSITION, *VELOCITY, *ACCELERATION, *QUATERNION, *RATE, *ANGULAR_ACCELERATION, *ROTORS,
           *ROTOR_RATES]


def signals(df: pd.DataFrame) -> Signals:
    """Body-frame :class:`qr.effects.Signals` of a state table."""
    R = quat_to_rot(df[QUATERNION].to_numpy())
    opt = [df[c].to_numpy() if all(x in df for x in c) else None
           for c in (U2_FORCE, U2_FORCE_RATE, U2_TORQUE, U2_TORQUE_RATE)]
    return Signals(R, to_body(R, df[VELOCITY].to_numpy()), to_body(R, df[ACCELERATION].to_numpy()),
                   df[RATE].to_numpy(), df[ANGULAR_ACCELERATION].to_numpy(), df[ROTORS].to_numpy(),
                   df[ROTOR_RATES].to_numpy(), df[POSITION].to_numpy(), *opt)


def check(df: pd.DataFrame, path=None) -> None:
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{path or 'state table'} lacks columns {missing}")
    if not np.all(np.diff(df["t"].to_numpy()) > 0):
        raise ValueError(f"{path or 'state table'}: t not strictly increasing")
