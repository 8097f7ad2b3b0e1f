"""Synthetic flights: the nominal-model controller flies the TRUE plant along a random trajectory.

``synthesize`` returns the canonical flight (noisy, with dropouts) and the
noise-free truth at the log stamps; ``write_synth`` writes ``flight.csv``,
``vehicle.yaml`` (the NOMINAL vehicle: what the user would believe),
``truth.json`` (effects, seed, settings) and ``truth.parquet`` (true states).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numba as nb
import numpy as np
import pandas as pd

from ..atomic import atomic_dir, write_json
from ..effects import validate_effect_list
from ..errors import QrInputError
from ..flight import POSITION, QUATERNION, ROTORS, write_flight
from ..frames import quat_multiply
from ..vehicle import save_vehicle, vehicle_from_dict
from .control import Gains, control, controller_params, for_lag
from ..plant_state import P_DELAY, P_MARKER, P_TAU, X_QUAT, X_RATE, X_ROTORS
from .plant import history_buffer, hover_state, plant_accels, rk4_step, tracked_point, true_params
from .trajectory import RandomTrajectory, TrajectoryConfig, random_trajectory, reference

MIN_SIM_RATE = 500.0


@dataclass
class NoiseConfig:
    position_std: float = 0.0005  # m, mocap position
    attitude_std: float = 0.003  # rad, mocap attitude (small rotation per axis)
    rotor_std: float = 0.005  # fraction of the hover rotor speed (RPM sensing: ~0.3 % on the Crazyflie logs)
    dropout: float = 0.005  # fraction of mocap samples left blank (short bursts)
    rotor_dropout: float = 0.0  # fraction of rotor-speed samples left blank


@dataclass
class SynthConfig:
    duration: float = 60.0  # s
    rate: float = 100.0  # Hz, log rate
    sim_rate: float = 1000.0  # Hz, integration rate (raised to a multiple of `rate`)
    seed: int = 0
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    noise_free: bool = False
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    gains: Gains = field(default_factory=Gains)
    controller: str = "lqr"  # "lee": the Crazyflie firmware's Lee controller along `setpoints` (qr.replay.synth)
    setpoints: dict | None = None  # controller "lee": qr.replay.synth.setpoints_record(...)


TRUTH_COLUMNS = (["t", "px", "py", "pz", "vx", "vy", "vz", "ax", "ay", "az", "qw", "qx", "qy", "qz",
                  "wx", "wy", "wz", "alx", "aly", "alz"] + ROTORS + ["ud1", "ud2", "ud3", "ud4"]
                 + ["ref_px", "ref_py", "ref_pz"])


@nb.njit(cache=True)
def _fly(x0, P, C, traj_args, dt, n_steps, log_every, hist):
    center, amp, freq, phase, yaw, yaw_rate, dips, dip_width, ramp = traj_args
    n_log = n_steps // log_every + 1
    out = np.empty((n_log, 31))
    x = x0.copy()
    u0 = x0[X_ROTORS].copy()
    r = P[P_MARKER].copy()
    zero = np.zeros(3)
    j = 0
    for k in range(n_steps + 1):
        t = k * dt
        p_ref, v_ref, a_ref, y_ref, yr_ref = reference(t, center, amp, freq, phase, yaw, yaw_rate,
                                                       dips, dip_width, ramp)
        u_cmd, _ = control(x, p_ref, v_ref, a_ref, y_ref, yr_ref, zero, C)
        if k % log_every == 0:
            if P[P_DELAY] > 0.0:  # delayed rotor map: the speeds acting now
                s = k - P[P_DELAY] / dt
                if s <= 0:
                    ue = u0.copy()
                else:
                    i0 = int(math.floor(s))
                    fr = s - i0
                    M = hist.shape[0]
                    ue = (1 - fr) * hist[i0 % M] + fr * hist[(i0 + 1) % M]
            else:
                ue = x[X_ROTORS].copy()
            a, alpha = plant_accels(x, ue, P, zero, zero)
            pm, vm, am = tracked_point(x, a, alpha, r)
            out[j, 0] = t
            out[j, 1:4] = pm
            out[j, 4:7] = vm
            out[j, 7:10] = am
            out[j, 10:14] = x[X_QUAT]
            out[j, 14:17] = x[X_RATE]
            out[j, 17:20] = alpha
            out[j, 20:24] = x[X_ROTORS]
            out[j, 24:28] = (u_cmd - x[X_ROTORS]) / P[P_TAU]
            out[j, 28:31] = p_ref
            j += 1
        if k < n_steps:
            x = rk4_step(x, u_cmd, P, zero, zero, dt, hist, u0, k)
    return out[:j]


def simulate_truth(vehicle, effects: list[dict], cfg: SynthConfig,
                   traj: RandomTrajectory | None = None) -> pd.DataFrame:
    """Noise-free true states of the tracked point at the log stamps."""
    effects = validate_effect_list(effects)
    if cfg.controller == "lee":
        from ..replay.synth import lee_truth

        return lee_truth(vehicle, effects, cfg.setpoints, cfg.duration, cfg.rate, sim_rate(cfg), TRUTH_COLUMNS)
    given = traj
    traj = traj or _trajectory(cfg)
    log_every = max(1, math.ceil(max(cfg.sim_rate, MIN_SIM_RATE) / cfg.rate))
    dt = 1.0 / (cfg.rate * log_every)
    n_steps = int(round(cfg.duration / dt))
    P = true_params(vehicle, effects)
    C = controller_params(vehicle, for_lag(cfg.gains, P[P_DELAY] + P[P_TAU]))
    p0, _, _, y0, _ = traj.sample(np.array([0.0]))
    x0 = hover_state(vehicle, p0[0], float(y0[0]))
    hist = history_buffer(P, dt, x0[X_ROTORS])
    out = _fly(x0, P, C, traj.args(), dt, n_steps, log_every, hist)
    if not np.all(np.isfinite(out)):
        t_bad = out[np.flatnonzero(~np.isfinite(out).all(axis=1))[0], 0]
        raise QrInputError("synthetic flight", f"the closed loop diverged at t = {t_bad:.2f} s",
                           "lower the trajectory's speed or tilt (--v-max, --tilt-max) or the effects' sizes")
    truth = pd.DataFrame(out, columns=TRUTH_COLUMNS)
    # the stamps a nanosecond clock logs (k dt carries the product's rounding, 22.499999999999996 for 22.5):
    # written whole (qr.flight.write_flight), they read back as the decimals a logger would write
    truth["t"] = np.round(truth["t"].to_numpy(), 9)
    lost = lost_control(truth)
    if lost:
        raise QrInputError("synthetic flight", f"the controller lost the vehicle: {lost}{_why_lost(vehicle, effects, cfg, given)}",
                           _what_flies(vehicle, effects, cfg, given))
    return truth


def sim_rate(cfg: SynthConfig) -> float:
    """The integration rate: ``sim_rate`` raised to a multiple of the log rate (and at least MIN_SIM_RATE)."""
    return cfg.rate * max(1, math.ceil(max(cfg.sim_rate, MIN_SIM_RATE) / cfg.rate))


def needed_tilt(vehicle, effects: list[dict], traj: RandomTrajectory, duration: float, step: float = 0.02
                ) -> tuple[np.ndarray, np.ndarray]:
    """Times and the tilt (deg) the thrust must take to fly ``traj`` exactly in the TRUE plant: the weight,
    the reference's acceleration and the effects' forces (the catalog's terms at the reference's state,
    hover-level rotor speeds for the thrust it needs; a body-frame drag turns with the attitude, so the
    attitude is solved for, a few fixed-point passes).  What the controller's tilt limit must leave room for."""
    from ..effects import Signals, total_term
    from ..frames import G

    t = np.arange(0.0, duration, step)
    p, v, a, yaw, _ = traj.sample(t)
    n = len(t)
    inertial = vehicle.mass * (a + np.array([0.0, 0.0, G]))  # the nominal model's m (a + g), world
    want = inertial.copy()
    b1c = np.stack([np.cos(yaw), np.sin(yaw), np.zeros(n)], axis=1)
    for _ in range(6):
        b3 = want / np.linalg.norm(want, axis=1, keepdims=True)
        b2 = np.cross(b3, b1c)
        b2 /= np.linalg.norm(b2, axis=1, keepdims=True)
        R = np.stack([np.cross(b2, b3), b2, b3], axis=2)
        u = np.repeat(np.sqrt(np.linalg.norm(want, axis=1) / vehicle.rotors.matrix[0].sum())[:, None], 4, axis=1)
        s = Signals(R=R, v_b=np.einsum("nji,nj->ni", R, v), a_b=np.einsum("nji,nj->ni", R, a), omega=np.zeros((n, 3)),
                    alpha=np.zeros((n, 3)), u=u, u_dot=np.zeros((n, 4)), p=p)
        f_a = total_term(effects, s, vehicle)[:, :3]
        # m (a + g) = R (T e3 + f_a): the thrust vector takes what the effects' force across body z does not
        want = inertial - np.einsum("nij,nj->ni", R, f_a * np.array([1.0, 1.0, 0.0]))
    return t, np.degrees(np.arctan2(np.hypot(want[:, 0], want[:, 1]), want[:, 2]))


def _trajectory(cfg: SynthConfig, v_max: float | None = None) -> RandomTrajectory:
    from dataclasses import replace

    tc = cfg.trajectory if v_max is None else replace(cfg.trajectory, v_max=v_max)
    return random_trajectory(np.random.default_rng(cfg.seed), cfg.duration, tc)


def _why_lost(vehicle, effects, cfg: SynthConfig, traj) -> str:
    """Where the trajectory needs more tilt than the controller's limit: the mechanism, with its numbers."""
    if traj is not None:  # a trajectory given by the caller: nothing to say about --v-max
        return ""
    t, tilt = needed_tilt(vehicle, effects, _trajectory(cfg), cfg.duration)
    i, limit = int(np.argmax(tilt)), cfg.gains.max_tilt_deg
    if tilt[i] <= limit:
        return ""
    first = t[np.argmax(tilt > limit)]
    return (f"; from t = {first:.1f} s the trajectory needs more tilt than the controller's limit of {limit:g} deg "
            f"against the weight, its acceleration and the effects' forces (up to {tilt[i]:.0f} deg at "
            f"t = {t[i]:.1f} s)")


def _what_flies(vehicle, effects, cfg: SynthConfig, traj) -> str:
    """The fix: the highest --v-max (to 0.05 m/s) whose trajectory needs no more tilt than the controller's
    limit, where the tilt is what lost the vehicle; else the generic advice."""
    generic = "lower the trajectory's speed or tilt (--v-max, --tilt-max) or the effects' sizes"
    limit = cfg.gains.max_tilt_deg
    fits = lambda v: needed_tilt(vehicle, effects, _trajectory(cfg, v), cfg.duration)[1].max() <= limit  # noqa: E731
    if traj is not None or fits(cfg.trajectory.v_max):
        return generic
    lo, hi = 0.0, cfg.trajectory.v_max
    while hi - lo > 0.05:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    if lo < 0.05:
        return "lower the effects' sizes: their forces alone need more tilt than the controller's limit"
    return (f"--v-max {np.floor(lo * 20) / 20:.2f} keeps the tilt it needs within the limit at this seed, or lower "
            "the effects' sizes")


# A flight the controller no longer tracks is not a flight a pilot would log: its chaos also makes its
# samples depend on the last bits of every floating-point operation (the BLAS kernel, the compiler).
MAX_TRACKING_ERROR = 1.0  # m


def lost_control(truth: pd.DataFrame) -> str | None:
    """Why the simulated vehicle was lost (tracking error over ``MAX_TRACKING_ERROR``, or upside down),
    or None."""
    t = truth["t"].to_numpy()
    err = np.linalg.norm(truth[POSITION].to_numpy() - truth[["ref_px", "ref_py", "ref_pz"]].to_numpy(), axis=1)
    qx, qy = truth["qx"].to_numpy(), truth["qy"].to_numpy()
    checks = ((err > MAX_TRACKING_ERROR, lambda i: f"{err[i]:.2f} m from the reference"),
              (1 - 2 * (qx**2 + qy**2) < 0, lambda i: "upside down"))
    first = [(np.flatnonzero(bad)[0], say) for bad, say in checks if bad.any()]
    if not first:
        return None
    i, say = min(first, key=lambda x: x[0])
    return f"{say(i)} at t = {t[i]:.2f} s"


def add_noise(truth: pd.DataFrame, vehicle, noise: NoiseConfig, rng: np.random.Generator) -> pd.DataFrame:
    """The canonical flight a motion-capture system and rotor-speed sensors would log."""
    n = len(truth)
    df = pd.DataFrame({"t": truth["t"].to_numpy()})
    df[POSITION] = truth[POSITION].to_numpy() + rng.normal(0.0, noise.position_std, (n, 3))
    dtheta = rng.normal(0.0, noise.attitude_std, (n, 3))
    half = np.linalg.norm(dtheta, axis=1, keepdims=True) / 2
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = np.where(half > 0, dtheta / (2 * half), 0.0)
    dq = np.hstack([np.cos(half), axis * np.sin(half)])
    df[QUATERNION] = quat_multiply(truth[QUATERNION].to_numpy(), dq)
    df[ROTORS] = np.abs(truth[ROTORS].to_numpy() + rng.normal(0.0, noise.rotor_std * vehicle.hover_speed, (n, 4)))
    _blank(df, POSITION + QUATERNION, noise.dropout, rng)
    _blank(df, ROTORS, noise.rotor_dropout, rng)
    return df


def _blank(df, cols, fraction, rng):
    """Blank ``fraction`` of the rows in bursts of 1-5 samples (radio or tracking loss)."""
    n = len(df)
    # bursts start in [1, n - 7] and reach row n - 3 at most: the first and last rows are kept, so
    # at most n - 3 rows can be blanked (more would never be reached)
    target = min(int(round(fraction * n)), n - 3) if n >= 8 else 0  # (a shorter flight has no room for bursts)
    mask = np.zeros(n, dtype=bool)
    blank = 0
    while blank < target:
        start = int(rng.integers(1, n - 6))
        end = start + int(rng.integers(1, 6))
        blank += int(np.count_nonzero(~mask[start:end]))
        mask[start:end] = True
    df.loc[mask, cols] = np.nan


def synthesize(vehicle, effects: list[dict], cfg: SynthConfig):
    """``(flight, truth)`` for ``vehicle`` with the catalog ``effects`` hidden in the plant."""
    truth = simulate_truth(vehicle, effects, cfg)
    if cfg.noise_free:
        flight = truth[["t", *POSITION, *QUATERNION, *ROTORS]].copy()
    else:
        rng = np.random.default_rng([cfg.seed, 1])
        flight = add_noise(truth, vehicle, cfg.noise, rng)
    return flight, truth


OUTPUTS = ("flight.csv", "vehicle.yaml", "truth.json", "truth.parquet")


def write_synth(outdir, vehicle, effects: list[dict], cfg: SynthConfig, force: bool = False,
                inputs=()) -> dict:
    """Write ``flight.csv``, ``vehicle.yaml`` (nominal), ``truth.json`` and ``truth.parquet``.

    ``outdir`` is checked before the flight is simulated (:func:`qr.outputs.check_out_dir`; ``inputs``:
    the files it must not hold; ``force``: write beside a folder's other files).
    """
    from ..outputs import check_out_dir

    check_out_dir(outdir, inputs=inputs, force=force, expected=OUTPUTS)
    effects = validate_effect_list(vehicle.effects) + validate_effect_list(effects)
    true_vehicle = vehicle.with_changes(effects=[]) if vehicle.effects else vehicle
    # the nominal vehicle.yaml knows neither the effects nor a learned torque remainder or wrench (qr.residual)
    # nor the rotor and airframe properties the catalog lacks (rotor inertia, per-rotor C_Q, flapping ratio):
    # all are the truth
    from ..vehicle import ROTOR_PROPERTIES

    nominal = true_vehicle.to_dict()
    learned = {k: nominal.pop(k) for k in ("torque_remainder", "residual", *ROTOR_PROPERTIES) if k in nominal}
    with atomic_dir(outdir, force=force, command="qr synth") as tmp:
        flight, truth = synthesize(true_vehicle, effects, cfg)
        vehicle = vehicle_from_dict(nominal) if learned else true_vehicle
        meta = {
            "schema": "qr.synth/1",
            "vehicle": vehicle.name,
            "effects": effects,
            **learned,
            "seed": cfg.seed,
            "duration": cfg.duration,
            "rate": cfg.rate,
            "noise_free": cfg.noise_free,
            "noise": asdict(cfg.noise),
            "trajectory": asdict(cfg.trajectory),
            "samples": len(flight),
            "controller": cfg.controller,
        }
        if cfg.controller == "lee":  # what qr replay rebuilds the flight from
            meta["setpoints"] = {**cfg.setpoints, "sim_rate_hz": sim_rate(cfg)}
        write_flight(flight, tmp / "flight.csv")
        save_vehicle(vehicle, tmp / "vehicle.yaml",
                     header="NOMINAL vehicle of a qr synth flight: the hidden effects are in truth.json")
        write_json(tmp / "truth.json", meta)
        truth.to_parquet(tmp / "truth.parquet", index=False)
    return meta

