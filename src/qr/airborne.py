"""Where a log is airborne: the rows a rigid-body model of free flight may explain.

A row is on the ground when the rotor-map thrust is low (``THRUST_OFF`` / ``THRUST_ON`` hysteresis, median over
``SMOOTH_S``, dips under ``MAX_DIP_S`` kept while moving) or the vehicle is within ``NEAR_M`` of a place it
rested; airborne stretches under ``MIN_AIRBORNE_S`` are ground too.  One rule for raw flights and state
tables.  docs/diagnose.md "What is flight".
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .errors import QrInputError

THRUST_ON = 0.5  # x m g: a vehicle with less cannot be climbing off the floor
THRUST_OFF = 0.25  # x m g: idle is ~0.01-0.1 m g; flight rarely dips this low
SMOOTH_S = 0.1  # s, running median of the thrust ratio
MAX_DIP_S = 0.5  # s, a low-thrust stretch without rest that is still flight
STILL_S = 0.5  # s, window over which a resting vehicle does not move ...
STILL_M = 0.02  # m, ... by more than this (mocap noise is ~0.1-1 mm)
NEAR_M = 0.05  # m, closer than this to a rest position is on (or touching) the ground
MIN_AIRBORNE_S = 0.5  # s
MOVE_M = 0.05  # m, a log whose position never spans this never flew


def _interp_nan(t: np.ndarray, x: np.ndarray, edges=None) -> np.ndarray:
    """Dropouts filled from the neighbouring samples (linear in time); before the first and after the
    last sample ``edges`` (default: the nearest sample)."""
    ok = np.isfinite(x)
    if ok.all() or not ok.any():
        return x
    return np.interp(t, t[ok], x[ok], left=edges, right=edges)


def _rolling(x: np.ndarray, n: int, how: str) -> np.ndarray:
    return getattr(pd.Series(x).rolling(n, center=True, min_periods=1), how)().to_numpy()


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` index ranges of the True runs of ``mask``."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def _hysteresis(x: np.ndarray, on: float, off: float) -> np.ndarray:
    """True from where ``x >= on`` until ``x < off`` (starting False)."""
    event = np.where(x >= on, 1, np.where(x < off, 0, -1))
    last = np.maximum.accumulate(np.where(event >= 0, np.arange(len(x)), -1))
    return np.where(last >= 0, event[np.maximum(last, 0)] == 1, False)


def thrust_ratio(df: pd.DataFrame, vehicle) -> np.ndarray:
    """Rotor-map thrust over m g per row (NaN where a rotor speed is missing)."""
    u = df[["u1", "u2", "u3", "u4"]].to_numpy(dtype=float)
    T = np.full(len(u), np.nan)
    ok = np.isfinite(u).all(axis=1)
    if ok.any():
        T[ok] = vehicle.rotors.thrust_torque(u[ok])[0]
    return T / (vehicle.mass * 9.81)


def airborne_mask(df: pd.DataFrame, vehicle) -> np.ndarray:
    """True for the rows of a flight (or state table) where the vehicle flies free of the ground."""
    t = df["t"].to_numpy(dtype=float)
    n = len(t)
    if n < 2:
        return np.zeros(n, dtype=bool)
    step = float(np.median(np.diff(t)))
    samples = lambda s: max(1, int(round(s / step)))  # noqa: E731
    # not logged before the first or after the last rotor sample (a logger that starts when armed):
    # unknown thrust, not flight
    r = _interp_nan(t, thrust_ratio(df, vehicle), edges=0.0)
    if not np.isfinite(r).any():
        return np.ones(n, dtype=bool)  # no rotor speeds at all: the filters refuse such a log
    r = _rolling(r, samples(SMOOTH_S) | 1, "median")  # odd: a step between rows stays there
    thrust = _hysteresis(r, THRUST_ON, THRUST_OFF)
    p = np.column_stack([_interp_nan(t, df[c].to_numpy(dtype=float)) for c in ("px", "py", "pz")])
    w = samples(STILL_S)
    spread = np.max([_rolling(p[:, k], w, "max") - _rolling(p[:, k], w, "min") for k in range(3)], axis=0)
    rest = ~thrust & (spread < STILL_M) & np.isfinite(spread)
    for a, b in _runs(~thrust):  # a short dip in thrust while moving is flight
        if t[b - 1] - t[a] < MAX_DIP_S and not rest[a:b].any() and 0 < a and b < n:
            thrust[a:b] = True
    ground = ~thrust
    if rest.any():  # near the previous or the next place it rested: on the ground
        idx = np.flatnonzero(rest)
        k = np.searchsorted(idx, np.arange(n))
        for j in (np.maximum(k - 1, 0), np.minimum(k, len(idx) - 1)):
            ground |= np.linalg.norm(p - p[idx[j]], axis=1) < NEAR_M
    air = ~ground
    for a, b in _runs(air):
        if t[b - 1] - t[a] < MIN_AIRBORNE_S:
            air[a:b] = False
    return air


def airborne_windows(df: pd.DataFrame, vehicle) -> list[tuple[float, float]]:
    """``[(t_first, t_last), ...]`` of the airborne stretches, in the log's own time."""
    t = df["t"].to_numpy(dtype=float)
    return [(float(t[a]), float(t[b - 1])) for a, b in _runs(airborne_mask(df, vehicle))]


def check_airborne(df: pd.DataFrame, vehicle, path=None) -> list[tuple[float, float]]:
    """The airborne windows of a canonical flight; refuses a log whose vehicle never flew.

    Also checks the rotor-speed unit (``qr.flight.check_hover_ratio``): first whether
    the vehicle moved at all (an idling vehicle's thrust would look like a unit error).
    """
    from .flight import POSITION, check_hover_ratio

    p = df[POSITION].to_numpy(dtype=float)
    ok = np.isfinite(p).all(axis=1)
    # robust to a few wild mocap samples
    span = np.max(np.diff(np.percentile(p[ok], [1, 99], axis=0), axis=0)) if ok.sum() > 1 else 0.0
    if span < MOVE_M:
        raise QrInputError(path, f"never airborne: the position never changes by more than {100 * MOVE_M:.0f} cm "
                                 f"(it spans {100 * span:.1f} cm)",
                           "give a log of a flight (this one is of a vehicle standing still)")
    check_hover_ratio(df, vehicle, path)
    windows = airborne_windows(df, vehicle)
    if not windows:
        ratio = thrust_ratio(df, vehicle)
        r = np.nanmax(ratio) if np.isfinite(ratio).any() else 0.0
        why = (f"the rotor-map thrust never exceeds {THRUST_ON:g} x m g (at most {r:.2f} x m g)"
               if r < THRUST_ON else
               f"with thrust on, it never rises {100 * NEAR_M:.0f} cm from where it rested, "
               f"for {MIN_AIRBORNE_S:g} s or more")
        raise QrInputError(path, f"never airborne: {why}",
                           "give a log of a flight; if it did fly, check the vehicle's mass and thrust_coeff")
    return windows


def hover_thrust_coeff(flights: list[pd.DataFrame], vehicle) -> tuple[float, list[float]]:
    """The thrust coefficient C_T that balances the weight over airborne flight: the vertical force
    balance ``m (a_z + g) = C_T Σ_i u_i² (R e_z)_z`` summed over every airborne row with all rotor speeds and
    the attitude present, with Σ a_z taken as zero (a flight that starts and ends near rest: the net change
    of vertical speed over seconds of flight is a fraction of a per cent of g).  Everything else that acts
    along the vertical on average (drag, a constant offset) is in it: the vehicle file's C_T of a vehicle
    whose rotor thrust was never measured.  Returns the pooled value and one per flight; the airborne rows
    are found with ``vehicle``'s C_T, then again with the estimate."""
    from .frames import quat_to_rot
    from .states import ROTORS

    veh = vehicle
    for _ in range(3):
        num, den, each = 0.0, 0.0, []
        for df in flights:
            u = df[ROTORS].to_numpy(float)
            q = df[["qw", "qx", "qy", "qz"]].to_numpy(float)
            ok = airborne_mask(df, veh) & np.isfinite(u).all(axis=1) & np.isfinite(q).all(axis=1)
            R33 = quat_to_rot(q[ok] / np.linalg.norm(q[ok], axis=1, keepdims=True))[:, 2, 2]
            d = float(np.sum(R33 * np.sum(u[ok] ** 2, axis=1)))
            n = vehicle.mass * 9.81 * int(ok.sum())
            num, den = num + n, den + d
            each.append(n / d)
        ct = num / den
        veh = vehicle.with_changes(thrust_coeff=ct, torque_coeff=vehicle.torque_coeff / vehicle.thrust_coeff * ct)
    return ct, each
