"""The rotor map: rotor speeds -> thrust and body torques.

One matrix ``B`` (4 x 4) maps squared rotor speeds to ``[T, Γx, Γy, Γz]``, ``F_i = C_T u_i^2``, ``Γ = Σ (y_i F_i,
-x_i F_i, yaw_sign_i C_Q u_i^2)``; the layouts ``plus`` (thesis eq. 4.3) and ``x`` and explicit rotors:
docs/ingest.md "Vehicle files".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PLUS_YAW_SIGNS = (-1.0, 1.0, -1.0, 1.0)
# the rotor map's median airborne thrust over the weight, m g, that a log may show: beyond it the speeds
# are in another unit or the coefficients are wrong (qr.flight refuses the log; the thrust effects stop there)
HOVER_RATIO_LIMITS = (1 / 3, 3.0)
SPEED_UNIT_NAMES = {"rpm": "rpm", "rad_s": "rad/s"}  # a vehicle file's rotor_speed_unit as a reader writes it


LAYOUTS = ("plus", "x")  # the named layouts (the rest: an explicit list of rotors)


def plus_positions(arm_length: float) -> np.ndarray:
    l = float(arm_length)
    return np.array([[l, 0.0], [0.0, l], [-l, 0.0], [0.0, -l]])


def x_positions(arm_length: float) -> np.ndarray:
    a = float(arm_length) / np.sqrt(2.0)
    return np.array([[a, -a], [a, a], [-a, a], [-a, -a]])


@dataclass(frozen=True)
class RotorMap:
    positions: np.ndarray  # (n_rotors, 2) body x, y of each rotor axis (m)
    yaw_signs: np.ndarray  # (n_rotors,) sign of each rotor's reaction torque about body z
    thrust_coeff: float
    torque_coeff: float

    @classmethod
    def from_layout(cls, layout, arm_length, thrust_coeff, torque_coeff) -> "RotorMap":
        if isinstance(layout, str) and layout in LAYOUTS:
            pos = {"plus": plus_positions, "x": x_positions}[layout](arm_length)
            signs = np.array(PLUS_YAW_SIGNS)
        else:
            pos = np.array([[float(r["x"]), float(r["y"])] for r in layout])
            signs = np.array([float(r["yaw_sign"]) for r in layout])
        return cls(pos, signs, float(thrust_coeff), float(torque_coeff))

    @property
    def n(self) -> int:
        return len(self.yaw_signs)

    @property
    def matrix(self) -> np.ndarray:
        """``B`` with ``[T, Γx, Γy, Γz] = B u²`` (eq. 4.3 for layout plus)."""
        ct, cq = self.thrust_coeff, self.torque_coeff
        x, y = self.positions[:, 0], self.positions[:, 1]
        return np.vstack([ct * np.ones(self.n), ct * y, -ct * x, cq * self.yaw_signs])

    @property
    def inverse(self) -> np.ndarray:
        """``B⁻¹`` by Gauss-Jordan elimination in a fixed order (partial pivoting): LAPACK's inverse rounds
        differently under each BLAS kernel, and the synthetic flights' controller flies with this one."""
        n = self.n
        a = [list(map(float, row)) + [1.0 if i == j else 0.0 for j in range(n)]
             for i, row in enumerate(self.matrix)]
        for c in range(n):
            p = max(range(c, n), key=lambda r: abs(a[r][c]))
            if a[p][c] == 0.0:
                raise np.linalg.LinAlgError("the rotor map is singular")
            a[c], a[p] = a[p], a[c]
            piv = a[c][c]
            a[c] = [x / piv for x in a[c]]
            for r in range(n):
                if r != c and a[r][c] != 0.0:
                    f = a[r][c]
                    a[r] = [x - f * y for x, y in zip(a[r], a[c])]
        return np.array([row[n:] for row in a])

    def wrench(self, u: np.ndarray) -> np.ndarray:
        """``[T, Γx, Γy, Γz]`` (N, 4) from rotor speeds (N, n_rotors)."""
        u = np.asarray(u, dtype=float)
        return (u * u) @ self.matrix.T

    def thrust_torque(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = self.wrench(u)
        return w[..., 0], w[..., 1:]


@dataclass(frozen=True)
class CommandMap:
    """Normalised motor commands ``c`` in [0, 1] -> rotor thrust: ``F_i = a_i + b_i c + k_i c²`` (N), with
    ``c`` scaled by ``vbat / v_ref`` where a reference voltage is given and the log has ``vbat``.

    qr works in rotor speeds: a command is read as the *equivalent* speed that gives the same thrust
    through the vehicle's ``C_T`` (``u = sqrt(F / C_T)``), so the rotor map, the effects and the plant are
    unchanged, and an error in the command map is a thrust error the diagnosis names (``thrust_gain``,
    ``motor_imbalance``, ``body_force_bias``). The yaw torque follows as ``C_Q u²``: a motor whose
    reaction torque is proportional to its thrust.
    """

    a: np.ndarray  # (n_rotors,)
    b: np.ndarray
    k: np.ndarray
    v_ref: float | None = None

    def thrust(self, c: np.ndarray, vbat: np.ndarray | None = None) -> np.ndarray:
        c = np.asarray(c, dtype=float)
        if self.v_ref is not None and vbat is not None:
            c = c * (np.asarray(vbat, dtype=float)[:, None] / self.v_ref)
        return self.a + self.b * c + self.k * c * c

    def equivalent_speeds(self, c: np.ndarray, thrust_coeff: float, vbat: np.ndarray | None = None) -> np.ndarray:
        """Rotor speeds (the vehicle's unit) with the commands' thrust; a non-positive thrust reads as 0."""
        return np.sqrt(np.maximum(self.thrust(c, vbat), 0.0) / thrust_coeff)
