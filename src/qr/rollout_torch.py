"""The rollout's differentiable twin (torch, float64): the same plant, step and errors as :mod:`qr.rollout`.

The compiled plant (:mod:`qr.sim.plant`) with the parameter vector ``P`` in its own layout, a learned wrench
(any torch module taking :mod:`qr.residual`'s features), RK4 over each window's own steps; differentiable in
``P`` and in the weights; :func:`window_errors` gives the per-step errors ``qr evaluate`` averages.  Held equal
to the compiled plant by ``tests/learn/test_rollout_torch.py``; docs/learn.md "The differentiable plant".
"""

from __future__ import annotations

import numpy as np
import torch

from .frames import G
from .residual import GROUPS, ORDER
from .plant_state import (P_B, P_BBIAS, P_CG, P_CQGAIN, P_FLAP, P_FLAP_PITCH, P_GE, P_GZ, P_HUB, P_J, P_LIN,
                          P_MARKER, P_MASS, P_QUAD, P_RDM, P_RDRAG, P_REM, P_REM_ON, P_ROTOR_J, P_SCALE, P_TBIAS,
                          P_TLIFT, P_UHOVER, P_WIND, P_YAW_GAIN, STATE_PARTS, X_POS, X_QUAT, X_RATE, X_VEL)
from .sim.plant import MIN_GROUND_HEIGHT

DTYPE = torch.float64


def body_features(inputs, v_b, w, g_b, u, speed_scale: float) -> torch.Tensor:
    """The residual's features ``φ`` (:func:`qr.residual.features`), in torch."""
    s = u / speed_scale
    parts = {"v_b": v_b, "omega": w, "g_b": g_b, "u": s, "u2": s * s}
    return torch.cat([parts[g] for g in ORDER if g in inputs], dim=-1)


class ResidualNet(torch.nn.Module):
    """The MLP of :mod:`qr.residual` in torch: ``s_out ⊙ MLP((φ − μ) / σ)`` (body force and torque)."""

    def __init__(self, inputs, width: int, depth: int, activation: str, input_mean, input_scale,
                 output_scale, rotor_speed_scale: float):
        super().__init__()
        self.inputs = tuple(g for g in ORDER if g in inputs)
        self.activation = activation
        self.rotor_speed_scale = float(rotor_speed_scale)
        n_in = sum(GROUPS[g] for g in self.inputs)
        dims = [n_in] + [width] * depth + [6]
        self.layers = torch.nn.ModuleList(torch.nn.Linear(a, b, dtype=DTYPE) for a, b in zip(dims[:-1], dims[1:]))
        self.register_buffer("input_mean", torch.as_tensor(np.asarray(input_mean, float), dtype=DTYPE))
        self.register_buffer("input_scale", torch.as_tensor(np.asarray(input_scale, float), dtype=DTYPE))
        self.register_buffer("output_scale", torch.as_tensor(np.asarray(output_scale, float), dtype=DTYPE))

    def forward(self, phi: torch.Tensor) -> torch.Tensor:
        z = (phi - self.input_mean) / self.input_scale
        for k, layer in enumerate(self.layers):
            z = layer(z)
            if k < len(self.layers) - 1:
                z = torch.tanh(z) if self.activation == "tanh" else torch.relu(z)
        return z * self.output_scale

    def wrench(self, v_b, w, g_b, u) -> torch.Tensor:
        return self(body_features(self.inputs, v_b, w, g_b, u, self.rotor_speed_scale))

    @classmethod
    def from_residual(cls, res) -> "ResidualNet":
        """The torch module of a :class:`qr.residual.Residual` (same weights)."""
        depth = len(res.weights) - 1
        width = res.weights[0].shape[0] if depth else 0
        net = cls(res.inputs, width, depth, res.activation, res.input_mean, res.input_scale, res.output_scale,
                  res.rotor_speed_scale)
        if any(W.shape[0] != width for W in res.weights[:-1]):  # uneven widths: rebuild the layers
            net.layers = torch.nn.ModuleList(torch.nn.Linear(W.shape[1], W.shape[0], dtype=DTYPE)
                                             for W in res.weights)
        with torch.no_grad():
            for layer, W, b in zip(net.layers, res.weights, res.biases):
                layer.weight.copy_(torch.as_tensor(W, dtype=DTYPE))
                layer.bias.copy_(torch.as_tensor(b, dtype=DTYPE))
        return net

    def to_residual(self):
        from .residual import Residual

        return Residual(self.inputs, self.activation,
                        tuple(layer.weight.detach().numpy().copy() for layer in self.layers),
                        tuple(layer.bias.detach().numpy().copy() for layer in self.layers),
                        self.input_mean.numpy().copy(), self.input_scale.numpy().copy(),
                        self.output_scale.numpy().copy(), self.rotor_speed_scale)


def _rotation_map() -> tuple[torch.Tensor, torch.Tensor]:
    """``M`` (16, 9) and ``E`` (9,): the entries of R (row by row) as ``vec(q qᵀ) M + E``
    (:func:`qr.frames_compiled.R_entries`: the plant's own formula, q not normalised)."""
    M = torch.zeros(4, 4, 9, dtype=DTYPE)
    for i, terms in enumerate([((2, 2, -2), (3, 3, -2)), ((1, 2, 2), (0, 3, -2)), ((1, 3, 2), (0, 2, 2)),
                               ((1, 2, 2), (0, 3, 2)), ((1, 1, -2), (3, 3, -2)), ((2, 3, 2), (0, 1, -2)),
                               ((1, 3, 2), (0, 2, -2)), ((2, 3, 2), (0, 1, 2)), ((1, 1, -2), (2, 2, -2))]):
        for j, k, c in terms:
            M[j, k, i] = c
    return M.reshape(16, 9), torch.tensor([1.0, 0, 0, 0, 1, 0, 0, 0, 1], dtype=DTYPE)


def _quat_rate_map() -> torch.Tensor:
    """``C`` (12, 4): ``q̇ = ½ vec(q ωᵀ) C`` is ``½ q ⊗ [0, ω]``."""
    C = torch.zeros(4, 3, 4, dtype=DTYPE)
    for out, terms in enumerate([((1, 0, -1), (2, 1, -1), (3, 2, -1)), ((0, 0, 1), (2, 2, 1), (3, 1, -1)),
                                 ((0, 1, 1), (3, 0, 1), (1, 2, -1)), ((0, 2, 1), (1, 1, 1), (2, 0, -1))]):
        for j, k, c in terms:
            C[j, k, out] = c
    return C.reshape(12, 4)


_RM, _RE = _rotation_map()
_QC = _quat_rate_map()
_QC_HALF = 0.5 * _QC  # exact: a power of two
_G = torch.tensor([0.0, 0.0, G], dtype=DTYPE)
_XY = torch.tensor([1.0, 1.0, 0.0], dtype=DTYPE)
_EZ = torch.tensor([[[0.0, 0.0, 1.0]]], dtype=DTYPE)


def rotation(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) body → world of quaternions (..., 4), scalar first."""
    qq = (q[..., :, None] * q[..., None, :]).flatten(-2)
    return torch.addmm(_RE, qq, _RM).unflatten(-1, (3, 3)) if qq.dim() == 2 else (qq @ _RM + _RE).unflatten(-1, (3, 3))


def _on(P: torch.Tensor, *slots) -> bool:
    """Whether the plant has a term: a ``P`` that requires grad has every term, else those with a non-zero
    parameter (as the compiled plant skips them; dropping an exact zero changes no sum)."""
    return P.requires_grad or any(bool(torch.any(s.detach() != 0)) for s in slots)


class Drive:
    """What the held rotor speeds ``u`` (…, 4) give, the same at every RK4 stage of a step: computed once
    per step, or for a whole window at once (…, H, 4) and taken step by step with :meth:`at`."""

    __slots__ = ("u", "T", "G", "usum", "h", "rem", "net")

    def __init__(self, plant: "Plant", u: torch.Tensor):
        self.u = u
        W = (u * u) @ plant.Bs
        self.T, self.G = W[..., :1], W[..., 1:]  # thrust, rotor torques
        self.usum = u.sum(-1, keepdim=True) if plant.rdrag_on else None
        # the rotors' momentum along body z, as a vector (0, 0, h_z): the gyroscopic moment −ω × h
        self.h = torch.nn.functional.pad(u @ plant.spin_J[:, None], (2, 0)) if plant.gyro else None
        # the torque remainder's and the network's terms in u (with their constants)
        self.rem = (((u / plant.uh) ** 2 - 1.0) @ plant.rem[6:10] + plant.rem[10]) if plant.rem is not None else None
        self.net = plant.net.drive(u) if plant.net is not None else None

    def at(self, k: int) -> "Drive":
        d = object.__new__(Drive)
        for name in Drive.__slots__:
            v = getattr(self, name)
            setattr(d, name, None if v is None else v[:, k])
        return d


class _FoldedNet:
    """A :class:`ResidualNet` rearranged for the plant's inner loop (same function, rounding aside): the
    input normalisation folded into the first layer, its columns split into the state's features (v_b, ω,
    g_b; g_b's sign folded in, so the plant passes the third row of R) and the rotor speeds' (u, u²:
    evaluated once per step, with the bias, by :meth:`drive`), the output scale folded into the last layer.
    Built from the weights once per rollout, so gradients reach them."""

    def __init__(self, net: "ResidualNet"):
        first = net.layers[0]
        W = first.weight / net.input_scale
        b = first.bias - W @ net.input_mean
        cols, k = {}, 0
        for g in net.inputs:
            cols[g] = (k, k + GROUPS[g])
            k += GROUPS[g]
        xs = [W[:, cols[g][0]:cols[g][1]] * (-1.0 if g == "g_b" else 1.0)
              for g in ("v_b", "omega", "g_b") if g in cols]
        self.groups = tuple(g for g in ("v_b", "omega", "g_b") if g in cols)
        self.us = tuple(g for g in ("u", "u2") if g in cols)
        self.Wu = torch.cat([W[:, cols[g][0]:cols[g][1]] for g in self.us], 1).T if self.us else None
        self.speed = net.rotor_speed_scale
        self.act = torch.tanh if net.activation == "tanh" else torch.relu
        layers = [(first.weight, first.bias)] + [(la.weight, la.bias) for la in net.layers[1:]]
        s = net.output_scale
        if len(layers) == 1:  # a linear map: the output scale on the first layer too
            Wx = torch.cat(xs, 1).T * s if xs else None
            self.Wx, self.b, self.Wu = Wx, b * s, self.Wu * s if self.Wu is not None else None
            self.hidden, self.last = (), None
        else:
            self.Wx, self.b = (torch.cat(xs, 1).T if xs else None), b
            self.hidden = tuple((la.weight.T, la.bias) for la in net.layers[1:-1])
            WL, bL = net.layers[-1].weight, net.layers[-1].bias
            self.last = (WL.T * s, bL * s)

    def drive(self, u: torch.Tensor) -> torch.Tensor:
        """The first layer's part in the rotor speeds, plus its bias: (…, width)."""
        if self.Wu is None:
            return self.b.expand(*u.shape[:-1], -1)
        sp = u / self.speed
        parts = {"u": sp, "u2": sp * sp}
        return torch.cat([parts[g] for g in self.us], -1) @ self.Wu + self.b

    def __call__(self, v_b, w, Rz, drive_net) -> torch.Tensor:
        x = {"v_b": v_b, "omega": w, "g_b": Rz}
        z = torch.addmm(drive_net, torch.cat([x[g] for g in self.groups], -1), self.Wx) if self.groups else drive_net
        if self.last is None:
            return z
        z = self.act(z)
        for W, b in self.hidden:
            z = self.act(torch.addmm(b, z, W))
        return torch.addmm(self.last[1], z, self.last[0])


class Plant:
    """The parameter vector's pieces as the derivative uses them, taken from ``P`` once per rollout
    (so a ``P`` that requires grad passes its gradient through every slot).  The terms in the rotor
    speeds alone are evaluated once per step (:class:`Drive`: they are held over it); a term whose
    parameters are all zero is skipped, as in the compiled plant (unless ``P`` requires grad)."""

    def __init__(self, P: torch.Tensor, residual=None, frozen: bool = False):
        sc = P[P_SCALE]
        B = P[P_B].reshape(4, 4)
        self.Bs = torch.cat([B[:3] * sc, B[3:] * P[P_CQGAIN] * P[P_YAW_GAIN]]).T  # u² → T, Γx, Γy, Γz
        # the rotors' angular momentum along body z per rotor speed (qr.sim.plant.rotor_momentum)
        self.spin_J = -torch.sign(B[3].detach()) * P[P_ROTOR_J]
        self.gyro = _on(P, P[P_ROTOR_J])
        self.lin, self.quad, self.bias = P[P_LIN], P[P_QUAD], P[P_BBIAS]
        self.lin_on, self.quad_on, self.bias_on = _on(P, self.lin), _on(P, self.quad), _on(P, self.bias)
        self.rdrag = P[P_RDRAG] * _XY
        self.rdrag_on = _on(P, P[P_RDRAG])
        self.ground = _on(P, P[P_GE])
        self.ge, self.gz, self.marker = P[P_GE], P[P_GZ], P[P_MARKER]
        zero = torch.zeros((), dtype=DTYPE)
        cx, cy = P[P_CG].unbind()
        self.cg = torch.stack([-cy, cx, zero])  # τ = r_cg × (0, 0, T)
        self.cg_on = _on(P, P[P_CG])
        k = P[P_FLAP]
        self.flap = torch.stack([torch.stack([zero, -k * P[P_FLAP_PITCH], zero]), torch.stack([k, zero, zero]),
                                 torch.zeros(3, dtype=DTYPE)])  # v_b @ flap = (k v_y, −k r v_x, 0)
        self.flap_on = _on(P, k)
        self.tbias, self.wind, self.mass, self.J = P[P_TBIAS], P[P_WIND], P[P_MASS], P[P_J]
        self.tbias_on, self.wind_on = _on(P, self.tbias), _on(P, self.wind)
        # the hubs (from the CG) where the rotor drag's H-force and translational lift act, where the plant has them
        self.hubs = _on(P, P[P_RDM], P[P_TLIFT])
        self.rdm, self.tlift = P[P_RDM], P[P_TLIFT]
        self.r = P[P_HUB].reshape(4, 3) - torch.nn.functional.pad(P[P_CG], (0, 1))
        self.rem = P[P_REM].reshape(3, 11).T if float(P[P_REM_ON].detach()) != 0.0 else None
        self.uh = P[P_UHOVER]
        self.residual, self.frozen = residual, frozen
        self.net = _FoldedNet(residual) if isinstance(residual, ResidualNet) else None

    def drive(self, u: torch.Tensor) -> Drive:
        return Drive(self, u)

    def accels(self, x: torch.Tensor, d) -> tuple[torch.Tensor, torch.Tensor]:
        """World acceleration of the CG and body angular acceleration at states ``x`` (B, 13) under the
        rotor speeds ``d`` (a :class:`Drive`, or the speeds (B, 4) themselves)."""
        if not isinstance(d, Drive):
            d = Drive(self, d)
        return self._accels(*x.split(STATE_PARTS, 1), d)

    def _accels(self, p, v, q, w, d):
        R = rotation(q)
        # [v; e_z]ᵀ R in one product: Rᵀ v and R's third row (Rᵀ e_z, minus the gravity direction g_b)
        v_b, Rz = (torch.cat([v[:, None, :], _EZ.expand(len(v), 1, 3)], 1) @ R).unbind(1)
        T, u = d.T, d.u
        f = None
        if self.lin_on:
            f = -self.lin * v_b
        if self.quad_on:
            f = (0.0 if f is None else f) - self.quad * v_b.abs() * v_b
        if self.bias_on:
            f = self.bias if f is None else f + self.bias
        if self.rdrag_on:
            f = (0.0 if f is None else f) - self.rdrag * d.usum * v_b
        if self.ground:  # the ground effect where the vehicle has one (the compiled plant skips it at k = 0)
            h = p[:, 2:3] + Rz @ self.marker[:, None] - self.gz
            T = T + self.ge * T / torch.clamp(h, min=MIN_GROUND_HEIGHT) ** 2
        fT = torch.nn.functional.pad(T, (2, 0))
        f = fT if f is None else f + fT
        t = d.G
        if self.cg_on:
            t = t + d.T * self.cg  # the thrust before the ground effect, as the compiled plant
        if self.tbias_on:
            t = t + self.tbias
        if self.flap_on:
            t = t + v_b @ self.flap
        if self.hubs:  # qr.sim.plant: H-force -k u_i [w_x, w_y, 0] and lift k_l (w_x² + w_y²) at hub r_i
            w_hub = v_b[:, None, :] + torch.linalg.cross(w[:, None, :].expand(-1, 4, -1), self.r.expand(len(w), -1, -1))
            wxy = w_hub * _XY
            lift = self.tlift * (wxy * wxy).sum(-1, keepdim=True)  # (B, 4, 1)
            F_hub = -self.rdm * u[:, :, None] * wxy + torch.nn.functional.pad(lift, (2, 0))
            t = t + torch.linalg.cross(self.r.expand(len(w), -1, -1), F_hub).sum(1)
            f = f + torch.nn.functional.pad(lift.sum(1), (2, 0))
        if self.rem is not None:  # the learned torque remainder (qr.torque_remainder), a linear map
            t = t + (torch.cat([v_b, w], -1) @ self.rem[:6] + d.rem)
        if self.net is not None:
            r = self.net(v_b, w, Rz, d.net)
            f = f + r[:, :3]
            t = t + r[:, 3:]
        elif self.residual is not None:
            r = self.residual.wrench(v_b, w, -Rz, u)  # g_b = Rᵀ (0, 0, −1)
            f = f + r[:, :3]
            t = t + r[:, 3:]
        a = (R @ f[:, :, None]).squeeze(2)
        if self.wind_on:
            a = a + self.wind
        a = a / self.mass - _G
        # J ω × ω − ω × h = (J ω + h) × ω, h the rotors' momentum (0, 0, h_z)
        Jw = self.J * w if d.h is None else self.J * w + d.h
        alpha = (t + torch.linalg.cross(Jw, w)) / self.J
        return a, alpha

    def deriv(self, x: torch.Tensor, d) -> torch.Tensor:
        if not isinstance(d, Drive):
            d = Drive(self, d)
        p, v, q, w = x.split(STATE_PARTS, 1)  # one op (slices would cost one gradient buffer each)
        a, alpha = self._accels(p, v, q, w, d)
        dq = (q[:, :, None] * w[:, None, :]).flatten(1) @ _QC_HALF
        if self.frozen:
            alpha = torch.zeros_like(alpha)
        return torch.cat([v, a, dq, alpha], -1)

    def rk4(self, x: torch.Tensor, d, dt: torch.Tensor) -> torch.Tensor:
        if not isinstance(d, Drive):
            d = Drive(self, d)
        h = dt[:, None]
        hh = 0.5 * h
        k1 = self.deriv(x, d)
        k2 = self.deriv(torch.addcmul(x, hh, k1), d)
        k3 = self.deriv(torch.addcmul(x, hh, k2), d)
        k4 = self.deriv(torch.addcmul(x, h, k3), d)
        s = torch.add(torch.add(torch.add(k1, k2, alpha=2.0), k3, alpha=2.0), k4)
        pv, q, w = torch.addcmul(x, h / 6.0, s).split((X_QUAT.start, *STATE_PARTS[2:]), 1)  # p and v, q, ω
        return torch.cat([pv, q / torch.linalg.vector_norm(q, dim=-1, keepdim=True), w], -1)


def accels(x: torch.Tensor, u: torch.Tensor, P: torch.Tensor, residual=None) -> tuple[torch.Tensor, torch.Tensor]:
    """World acceleration of the CG (B, 3) and body angular acceleration (B, 3): ``qr.sim.plant._accels``."""
    return Plant(P, residual).accels(x, u)


def deriv(x: torch.Tensor, u: torch.Tensor, P: torch.Tensor, residual=None, frozen: bool = False) -> torch.Tensor:
    """Derivatives (B, 13) of p, v, q, ω (``qr.sim.plant.rigid_body_deriv``); ``frozen``: ω held."""
    return Plant(P, residual, frozen).deriv(x, u)


def rk4(x: torch.Tensor, u: torch.Tensor, dt: torch.Tensor, P: torch.Tensor, residual=None,
        frozen: bool = False) -> torch.Tensor:
    """One RK4 step (rotor speeds ``u`` held over it; ``dt`` (B,)), the quaternion renormalised."""
    return Plant(P, residual, frozen).rk4(x, u, dt)


def _marker_terms(x: torch.Tensor, r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``R r`` and ``R (ω × r)`` (world, (..., 3)), the tracked point's offsets from the CG."""
    R = rotation(x[..., X_QUAT])
    wr = torch.linalg.cross(x[..., X_RATE], r.expand_as(x[..., X_RATE]))
    return (R @ r[:, None]).squeeze(-1), (R @ wr[..., None]).squeeze(-1)


def rollout(X0: torch.Tensor, U: torch.Tensor, dt: torch.Tensor, P: torch.Tensor, residual=None,
            frozen: bool = False) -> torch.Tensor:
    """Predicted tracked-point states (B, H, 13) from start states ``X0`` (B, 13: p, v of the tracked
    point, q, ω) driven by the rotor speeds ``U`` (B, H, 4; ``U[:, h-1]`` acts over step h) over the steps
    ``dt`` (B, H): ``qr.rollout``'s windows (the caller applies the actuator delay to ``U``)."""
    plant = Plant(P, residual, frozen)
    r = P[P_MARKER]
    pr, vr = _marker_terms(X0, r)
    x = torch.cat([X0[:, X_POS] - pr, X0[:, X_VEL] - vr, X0[:, X_QUAT.start:]], -1)
    drive = plant.drive(U)  # every step's rotor-speed terms at once
    jump = None
    if plant.gyro and not frozen and U.shape[1] > 1:  # the held speeds jump: the body takes the rotors' momentum
        dw = (U[:, 1:] - U[:, :-1]) @ plant.spin_J / plant.J[2]  # (B, H − 1)
        jump = torch.nn.functional.pad(dw[..., None], (X_RATE.start + 2, 0))  # on ω_z
    out = []
    for h in range(U.shape[1]):
        if h > 0 and jump is not None:
            x = x - jump[:, h - 1]
        x = plant.rk4(x, drive.at(h), dt[:, h])
        out.append(x)
    X = torch.stack(out, 1)
    pr, vr = _marker_terms(X, r)
    return torch.cat([X[..., X_POS] + pr, X[..., X_VEL] + vr, X[..., X_QUAT.start:]], -1)


def _norm(d: torch.Tensor) -> torch.Tensor:
    """Euclidean norm over the last axis with a finite gradient at zero."""
    s = (d * d).sum(-1)
    return torch.sqrt(torch.where(s > 0, s, torch.ones_like(s))) * (s > 0)


def window_errors(pred: torch.Tensor, tp, tq, tv, tw) -> torch.Tensor:
    """Per-step errors (B, H, 4) of p (m), v (m/s), R (rad: angle of q_true⁻¹ ⊗ q) and ω (rad/s), as
    ``qr.rollout`` sums them; NaN where the truth (B, H, ·) is missing (with a zero gradient there, so a
    loss may mask them)."""
    truth = [tp, tq, tv, tw]
    present = torch.stack([torch.isfinite(x).all(-1) for x in (tp, tv, tq, tw)], -1)
    tp, tq, tv, tw = (torch.nan_to_num(x) for x in truth)
    d = (pred[..., X_QUAT] * tq).sum(-1).abs()
    E = torch.stack([_norm(pred[..., X_POS] - tp), _norm(pred[..., X_VEL] - tv),
                     2.0 * torch.acos(torch.clamp(d, max=1.0)), _norm(pred[..., X_RATE] - tw)], -1)
    return torch.where(present, E, torch.full_like(E, float("nan")))
