"""Flights drawn from the filters' own models: the only data with a TRUE process-noise intensity.

Each position axis, world rotation axis and rotor is an integrator chain
driven by white noise of known intensity ``q`` (sampled exactly over each
irregular step), observed with white noise of known variance ``r``; mocap and
rotor dropouts are blanked.  Written independently of ``qr.estimation``:
the step covariance is built from its closed form, and the attitude is
integrated with scipy rotations.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation


def _chain(rng, dts, m, q, channels, x0):
    """States (N, channels, m) of order-m chains with white noise of intensity q on the m-th derivative."""
    a = np.arange(m - 1, -1, -1)  # power of dt carried by each state's noise
    sigma = 1.0 / (np.array([math.factorial(i) for i in a])[:, None] * np.array([math.factorial(i) for i in a])[None, :]
                   * (a[:, None] + a[None, :] + 1))
    L = np.linalg.cholesky(sigma)
    x = np.zeros((len(dts) + 1, channels, m))
    x[0, :, 0] = x0
    for k, dt in enumerate(dts):
        Phi = np.array([[dt ** (j - i) / math.factorial(j - i) if j >= i else 0.0 for j in range(m)]
                        for i in range(m)])
        w = math.sqrt(q * dt) * (dt ** a)[:, None] * (L @ rng.standard_normal((m, channels)))
        x[k + 1] = x[k] @ Phi.T + w.T
    return x


def model_flight(seed=0, duration=30.0, rate=100.0, jitter=0.3, dropout=0.02,
                 q_pos=4.0e3, r_pos=2.5e-7, q_att=5.0e3, r_att=9e-6, q_mot=2.0e12, r_mot=2500.0, hover=5000.0):
    """``(flight, truth)``: a canonical flight with irregular stamps and dropouts, and its noise-free states."""
    rng = np.random.default_rng(seed)
    n = int(duration * rate)
    dts = (1.0 / rate) * (1 + rng.uniform(-jitter, jitter, n - 1))
    t = np.concatenate([[0.0], np.cumsum(dts)])
    pos = _chain(rng, dts, 4, q_pos, 3, np.array([0.0, 0.0, 1.0]))
    rot = _chain(rng, dts, 4, q_att, 3, np.zeros(3))  # world rotation angle, ω, α, α̇ per axis
    mot = _chain(rng, dts, 3, q_mot, 4, np.full(4, hover))
    R = [Rotation.identity()]
    for k in range(n - 1):
        R.append(Rotation.from_rotvec(rot[k + 1, :, 0] - rot[k, :, 0]) * R[-1])
    quat = Rotation.concatenate(R).as_quat(scalar_first=True)
    noise = Rotation.from_rotvec(rng.normal(0, math.sqrt(r_att), (n, 3)))
    flight = pd.DataFrame({"t": t})
    flight[["px", "py", "pz"]] = pos[:, :, 0] + rng.normal(0, math.sqrt(r_pos), (n, 3))
    flight[["qw", "qx", "qy", "qz"]] = (Rotation.concatenate(R) * noise).as_quat(scalar_first=True)
    flight[["u1", "u2", "u3", "u4"]] = mot[:, :, 0] + rng.normal(0, math.sqrt(r_mot), (n, 4))
    gone = rng.random(n) < dropout
    gone[:5] = False
    flight.loc[gone, ["px", "py", "pz", "qw", "qx", "qy", "qz"]] = np.nan
    flight.loc[rng.random(n) < dropout, "u3"] = np.nan  # one rotor drops out on its own
    truth = pd.DataFrame({"t": t, "qw": quat[:, 0], "qx": quat[:, 1], "qy": quat[:, 2], "qz": quat[:, 3]})
    truth[["vx", "vy", "vz"]] = pos[:, :, 1]
    truth[["w_world_x", "w_world_y", "w_world_z"]] = rot[:, :, 1]
    return flight, truth
