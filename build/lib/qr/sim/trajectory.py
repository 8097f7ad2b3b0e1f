"""Reference trajectories: smooth random flights for ``qr synth``.

A random flight is a sum of sinusoids per axis under a quintic fade-in, scaled
so the peak horizontal speed and the peak tilt (``atan(|a_h| / (g + a_z))``) hit
their targets; yaw oscillates and may spin; optional Gaussian dips take the
vehicle down to a low height above the floor (ground effect).  Everything is
analytic, so position, velocity, acceleration and yaw rate agree exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from ..frames import G


@dataclass
class TrajectoryConfig:
    v_max: float = 2.5  # m/s, peak horizontal speed
    tilt_max_deg: float = 25.0  # peak tilt the reference asks for
    z0: float = 1.0  # m, mean height
    z_amp: float = 0.4  # m, vertical excursion
    yaw_amp_deg: float = 60.0
    yaw_rate: float = 0.0  # rad/s, constant spin ("tumbling yaw") on top
    low_passes: bool = False  # dips towards the floor
    low_height: float = 0.12  # m, lowest height of a dip
    dip_every_s: float = 12.0
    ramp_s: float = 3.0  # fade-in from hover
    components: int = 3


@dataclass
class RandomTrajectory:
    center: np.ndarray
    amp: np.ndarray  # (3, K)
    freq: np.ndarray  # (3, K) rad/s
    phase: np.ndarray  # (3, K)
    yaw: np.ndarray = field(default_factory=lambda: np.zeros((3, 1)))  # rows amp, freq, phase
    yaw_rate: float = 0.0
    dips: np.ndarray = field(default_factory=lambda: np.zeros((2, 0)))  # rows time, depth
    dip_width: float = 1.0
    ramp: float = 3.0

    def args(self):
        return (self.center, self.amp, self.freq, self.phase, self.yaw, self.yaw_rate,
                self.dips, self.dip_width, self.ramp)

    def sample(self, t: np.ndarray):
        """p, v, a (N, 3), yaw, yaw rate (N,) at times ``t``."""
        out = [reference(float(ti), *self.args()) for ti in np.atleast_1d(t)]
        p, v, a, y, yr = (np.array([o[i] for o in out]) for i in range(5))
        return p, v, a, y, yr


@nb.njit(cache=True)
def _fade(t, ramp):
    if t >= ramp:
        return 1.0, 0.0, 0.0
    if t <= 0.0:
        return 0.0, 0.0, 0.0
    s = t / ramp
    e = s**3 * (10 - 15 * s + 6 * s * s)
    de = 30 * s * s * (1 - s) ** 2 / ramp
    dde = 60 * s * (1 - s) * (1 - 2 * s) / ramp**2
    return e, de, dde


@nb.njit(cache=True)
def reference(t, center, amp, freq, phase, yaw, yaw_rate, dips, dip_width, ramp):
    e, de, dde = _fade(t, ramp)
    p = center.copy()
    v = np.zeros(3)
    a = np.zeros(3)
    for i in range(3):
        s = 0.0
        ds = 0.0
        dds = 0.0
        for k in range(amp.shape[1]):
            arg = freq[i, k] * t + phase[i, k]
            s += amp[i, k] * (math.sin(arg) - math.sin(phase[i, k]))
            ds += amp[i, k] * freq[i, k] * math.cos(arg)
            dds -= amp[i, k] * freq[i, k] ** 2 * math.sin(arg)
        p[i] += e * s
        v[i] += de * s + e * ds
        a[i] += dde * s + 2 * de * ds + e * dds
    for j in range(dips.shape[1]):
        tj, d = dips[0, j], dips[1, j]
        z = (t - tj) / dip_width
        g = math.exp(-0.5 * z * z)
        p[2] -= d * g
        v[2] -= d * g * (-z / dip_width)
        a[2] -= d * g * (z * z - 1) / dip_width**2
    y = 0.0
    dy = 0.0
    for k in range(yaw.shape[1]):
        arg = yaw[1, k] * t + yaw[2, k]
        y += yaw[0, k] * (math.sin(arg) - math.sin(yaw[2, k]))
        dy += yaw[0, k] * yaw[1, k] * math.cos(arg)
    yaw_val = e * (y + yaw_rate * t)
    yaw_dot = de * (y + yaw_rate * t) + e * (dy + yaw_rate)
    return p, v, a, yaw_val, yaw_dot


def random_trajectory(rng: np.random.Generator, duration: float, cfg: TrajectoryConfig | None = None
                      ) -> RandomTrajectory:
    cfg = cfg or TrajectoryConfig()
    K = cfg.components
    freq = np.empty((3, K))
    freq[:2] = 2 * np.pi * rng.uniform(0.06, 0.3, (2, K))
    freq[2] = 2 * np.pi * rng.uniform(0.08, 0.3, K)
    phase = rng.uniform(0, 2 * np.pi, (3, K))
    amp = rng.uniform(0.4, 1.0, (3, K))
    amp[2] *= cfg.z_amp / amp[2].sum()
    yaw = np.vstack([rng.uniform(0.4, 1.0, K), 2 * np.pi * rng.uniform(0.05, 0.25, K),
                     rng.uniform(0, 2 * np.pi, K)])
    yaw[0] *= math.radians(cfg.yaw_amp_deg) / yaw[0].sum()
    center = np.array([0.0, 0.0, cfg.z0])
    traj = RandomTrajectory(center, amp, freq, phase, yaw, cfg.yaw_rate, np.zeros((2, 0)), 1.0, cfg.ramp_s)

    # scale the horizontal amplitudes to the speed and tilt targets, measured on a grid
    t = np.arange(0.0, duration, 0.02)
    _, v, a, _, _ = traj.sample(t)
    v_h = np.hypot(v[:, 0], v[:, 1]).max()
    tilt = np.arctan2(np.hypot(a[:, 0], a[:, 1]), G + a[:, 2]).max()
    scale = min(cfg.v_max / v_h, math.tan(math.radians(cfg.tilt_max_deg)) / math.tan(tilt))
    traj.amp[:2] *= scale
    if cfg.low_passes:
        times = np.arange(cfg.ramp_s + 4.0, duration - 3.0, cfg.dip_every_s)
        p, _, _, _, _ = traj.sample(times)
        traj.dips = np.vstack([times, np.maximum(p[:, 2] - cfg.low_height, 0.0)])
    return traj
