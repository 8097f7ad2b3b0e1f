"""The Lee controller held to the firmware's own outputs: the payload flights log, at 500 Hz, the state the
controller used (``stateEstimate.*``, ``gyro.*``), its references (``ctrlLee.rpyd*``: the desired attitude,
``ctrlLee.omegar*``: ω_r) and its outputs (``ctrlLee.thrustSi``, ``ctrlLee.torque*``).  Shared by the test and
``benchmarks/replay.py --firmware`` (every payload figure-8 flight)."""

from __future__ import annotations

import numpy as np

GAP_TICKS = 5  # a log gap longer than this many controller ticks: the attitude integral is taken up again there


def reproduce(path, timescale: float, mass: float = 0.0444, height: float = 0.75) -> dict:
    """Fed the logged state (and, for the torques, the logged references), what qr's Lee controller
    computes against what the firmware logged: RMS and spread per output.

    Setpoints: the figure-8 from the payload README's start point (0, 0, ``height``) with the README's
    ``ctrlLee.mass``; only its start time is fitted (to the logged thrust).  The attitude integral is not
    logged: it is taken from the logged torque at the first row and after each gap of the log longer than
    ``GAP_TICKS`` ticks (the firmware's integral over a gap is unknown); a shorter gap is bridged with the
    row's own attitude error."""
    from qr.frames import quat_to_rot
    from qr.ingest.cf_usd import read_fast
    from qr.replay.alignment import from_thrust
    from qr.replay.lee import G_DT, LeeGains, attitude_loop, lee_step
    from qr.replay.setpoints import Setpoints, read_pieces
    from scipy.spatial.transform import Rotation

    from conftest import DATA

    traj = read_pieces(DATA.parent / "crazyswarm2-figure8" / "figure8.csv")
    f = read_fast(path)
    t = f["t"].to_numpy()
    p, v = f[["px", "py", "pz"]].to_numpy(), f[["vx", "vy", "vz"]].to_numpy()
    R = quat_to_rot(f[["qw", "qx", "qy", "qz"]].to_numpy())
    w = f[["gx", "gy", "gz"]].to_numpy()
    T_log = f["ctrlLee_thrustSi"].to_numpy()
    tau_log = f[["ctrlLee_torquex", "ctrlLee_torquey", "ctrlLee_torquez"]].to_numpy()
    Rd_log = Rotation.from_euler("xyz", f[["ctrlLee_rpydx", "ctrlLee_rpydy", "ctrlLee_rpydz"]].to_numpy()).as_matrix()
    wr_log = f[["ctrlLee_omegarx", "ctrlLee_omegary", "ctrlLee_omegarz"]].to_numpy()
    gains = LeeGains.firmware()
    G = gains.vector(mass)
    al = from_thrust(t, p, v, R, T_log, traj, timescale, gains, mass=mass, origin=(0.0, 0.0, height))
    sp = Setpoints(traj, timescale, al.offset_s, (0.0, 0.0, height)).at(t)
    ticks = np.maximum(1, np.round(np.diff(t, prepend=t[0] - G[G_DT]) / G[G_DT]).astype(int))
    n = len(t)
    tau_refs, tau_full, T_full, angle = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros(n)
    i_refs, i_full = np.zeros(6), np.zeros(6)
    KI = np.asarray(gains.KI)
    restarts = 0
    for k in range(n):
        restart = k == 0 or ticks[k] > GAP_TICKS
        wd = Rd_log[k].T @ R[k] @ wr_log[k]  # ω_d of the logged ω_r
        for _ in range(0 if restart else ticks[k] - 1):
            attitude_loop(R[k], w[k], Rd_log[k], wd, G, i_refs)
            lee_step(p[k], v[k], R[k], w[k], sp["p"][k], sp["v"][k], sp["a"][k], sp["j"][k], sp["yaw"][k],
                     sp["yaw_rate"][k], G, i_full)
        ta, _ = attitude_loop(R[k], w[k], Rd_log[k], wd, G, i_refs)
        T, tb, Rd, _ = lee_step(p[k], v[k], R[k], w[k], sp["p"][k], sp["v"][k], sp["a"][k], sp["j"][k], sp["yaw"][k],
                                sp["yaw_rate"][k], G, i_full)
        if restart:  # the integral from this row's logged torque (the row itself is then not scored)
            restarts += 1
            i_refs[3:] += (ta - tau_log[k]) / KI
            i_full[3:] += (tb - tau_log[k]) / KI
            ta, tb = tau_log[k].copy(), tau_log[k].copy()
        tau_refs[k], tau_full[k], T_full[k] = ta, tb, T
        angle[k] = np.degrees(np.arccos(np.clip((np.trace(Rd.T @ Rd_log[k]) - 1) / 2, -1, 1)))

    def rms(x):
        return np.sqrt(np.mean(x ** 2, axis=0))

    # the gains the logged torques identify: least squares of the law on its terms (the integral's start free)
    E = np.einsum("nji,njk->nik", Rd_log, R) - np.einsum("nji,njk->nik", R, Rd_log)
    eR = 0.5 * np.stack([E[:, 2, 1], E[:, 0, 2], E[:, 1, 0]], axis=1)
    J = np.asarray(gains.J)
    y = tau_log - np.cross(w, J * w)
    integral = np.cumsum(eR * ticks[:, None] * G[G_DT], axis=0)
    fitted = np.array([np.linalg.lstsq(np.stack([-eR[:, i], -(w[:, i] - wr_log[:, i]), -integral[:, i], -np.ones(n)], 1),
                                       y[:, i], rcond=None)[0][:3] for i in range(3)]).T  # rows KR, Komega, KI
    return {"offset_s": al.offset_s, "samples": n, "restarts": restarts,
            "torque_refs_rms": rms(tau_refs - tau_log), "torque_full_rms": rms(tau_full - tau_log),
            "torque_spread": tau_log.std(axis=0), "thrust_rms": float(rms(T_full - T_log)),
            "thrust_spread": float(T_log.std()), "thrust_mean_error": float(np.mean(T_full - T_log)),
            "attitude_ref_rms_deg": float(rms(angle)), "fitted_gains": fitted,
            "gains": np.array([gains.KR, gains.Komega, gains.KI])}
