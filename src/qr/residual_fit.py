"""Training a learned wrench (:mod:`qr.residual`) through the rollout (docs/spec/hybrid.md, docs/learn.md).

The loss is the ``qr evaluate`` protocol's own error over H steps (:mod:`qr.rollout_torch`), each signal over
``rate_frozen``'s, back-propagated through every RK4 stage; Adam from a zero-output network, early stopping
on the validation windows.  The loss's weights and why: docs/learn.md "A residual trained through the rollout".
Deterministic: one torch thread, deterministic algorithms, every random draw from ``seed``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from .allowed import check_fields, check_known, setting, show
from .errors import QrInputError
from .plant_state import X_QUAT, X_RATE, X_VEL
from .residual import ACTIVATIONS, GROUPS
from .rollout import MODEL, QUANTITIES, RATE_FROZEN, Windows, score_plant, summary

DEFAULTS_FILE = "src/qr/residual_fit.py"


def _groups() -> list[str]:
    return list(GROUPS)


@dataclass
class LossWeights:
    KEY: ClassVar[str] = "learn.signal_weights"
    p: float = setting(1.0, ge=0)  # position
    v: float = setting(1.0, ge=0)  # velocity
    R: float = setting(1.0, ge=0)  # attitude angle
    w: float = setting(1.0, ge=0)  # body rate

    def __post_init__(self):
        check_fields(self, lambda name: f"{self.KEY}.{name}", DEFAULTS_FILE)
        if not any(getattr(self, q) > 0 for q in QUANTITIES):
            raise QrInputError(self.KEY, "every signal weight is 0", "give at least one a positive weight")

    def vector(self) -> np.ndarray:
        return np.array([getattr(self, q) for q in QUANTITIES], float)


@dataclass
class ResidualConfig:
    """``qr learn residual``'s settings (config group ``learn``, option ``residual``)."""

    KEY: ClassVar[str] = "learn"
    inputs: list[str] = setting(kind="names", names=_groups, nonempty=True,
                                default_factory=lambda: ["v_b", "omega", "g_b", "u2"])
    width: int = setting(32, "integer", ge=1, le=1024)  # units per hidden layer
    depth: int = setting(2, "integer", ge=0, le=6)  # hidden layers (0: a linear map)
    activation: str = "relu"  # relu | tanh (docs/learn.md, "Beyond the training envelope": chosen on validation)
    horizon: int = setting(50, "integer", ge=1, le=1000)  # H: steps of each training window
    horizon_power: float = setting(0.0, ge=-4, le=4)  # w_h ∝ h^p over h = 1..H (0: every step alike)
    signal_weights: LossWeights = field(default_factory=LossWeights)  # λ_s of p, v, R, ω
    epochs: int = setting(10, "integer", ge=1, le=100_000)  # at most
    patience: int = setting(3, "integer", ge=1)  # epochs without a better validation loss before stopping
    batch: int = setting(64, "integer", ge=1)  # windows per step
    lr: float = setting(3e-3, gt=0, le=1)  # Adam's step size
    weight_decay: float = setting(0.0, ge=0)  # on the weights (AdamW)
    stride: int = setting(4, "integer", ge=1)  # every stride-th start trains (neighbouring windows overlap)
    validation: float = setting(0.2, gt=0, lt=1)  # share of the flights (or of a lone flight's time) kept out
    clip: float = setting(1.0, gt=0)  # gradient norm clipped to this
    # false: the vehicle file's linear torque remainder (a hybrid of qr diagnose) is dropped and the network
    # trained on top of the physical model alone
    keep_remainder: bool = True
    # residuals trained on the training flights resampled by flight, each with its own seed, saved beside the
    # hybrid (qr.ensemble): the band qr evaluate draws around it (qr.bands); 0: none, no band
    members: int = setting(5, "integer", ge=0, le=100)
    # each member starts from the trained network and is fine-tuned on its resample for at most this many
    # epochs (learn.patience stops it early), keeping its best validation epoch (never the start itself)
    member_epochs: int = setting(3, "integer", ge=1, le=100_000)
    # processes training members at once (one torch thread each); 0: min(2, cores).  Same bytes for any value
    member_jobs: int = setting(0, "integer", ge=0, le=256)
    force_scale: float = setting(0.05, gt=0)  # output scale of the force, in m g
    torque_scale: float = setting(0.05, gt=0)  # ... of the torque, in m g times the mean rotor arm

    def __post_init__(self):
        if isinstance(self.signal_weights, dict):
            check_known(LossWeights.KEY, self.signal_weights, LossWeights, DEFAULTS_FILE)
            self.signal_weights = LossWeights(**self.signal_weights)
        check_fields(self, lambda name: f"{self.KEY}.{name}", DEFAULTS_FILE)
        if self.activation not in ACTIVATIONS:
            raise QrInputError("learn.activation", f"{show(self.activation)} is not allowed",
                               f"use one of {', '.join(ACTIVATIONS)}")

    @classmethod
    def from_dict(cls, d: dict) -> "ResidualConfig":
        from dataclasses import fields

        names = {f.name for f in fields(cls)}
        d = {k: v for k, v in dict(d or {}).items() if k not in ResidualNode.RUN_KEYS}
        check_known(cls.KEY, d, cls, DEFAULTS_FILE)
        return cls(**{k: v for k, v in d.items() if k in names})

    def horizon_weights(self) -> np.ndarray:
        w = np.arange(1, self.horizon + 1, dtype=float) ** self.horizon_power
        return w / w.sum()


@dataclass
class ResidualNode(ResidualConfig):
    """The config group ``learn`` as ``qr learn residual`` composes it (``conf/learn/residual.yaml``): the
    settings, and what the command line gives (the flights, the vehicle, the output folder)."""

    RUN_KEYS: ClassVar[tuple] = ("flights", "vehicle", "out", "force", "kind")
    kind: str = "residual"
    flights: list[str] = field(default_factory=list)
    vehicle: str = ""
    out: str = ""
    force: bool = False


# ---- the windows ---------------------------------------------------------------------------------

@dataclass
class Piece:
    """One gap-free piece of a flight, its windows (``qr.rollout.Windows``) and which starts go where."""

    flight: str
    windows: Windows
    train: np.ndarray  # start indices that train
    val: np.ndarray  # start indices that validate


def full_starts(w: Windows, H: int) -> np.ndarray:
    """Scored starts whose window lies wholly in the piece."""
    i = np.flatnonzero(w.ok)
    return i[i + H < len(w.t)]


def split(pieces: list[tuple[str, Windows]], H: int, fraction: float, stride: int,
          validation: list[str] | None = None, by: str = "flight") -> tuple[list[Piece], dict]:
    """Training and validation starts: whole flights (``validation``, chosen by :func:`qr.holdout.validation`
    — ``by`` says how; default every ``round(1/fraction)``-th flight, at least one) when there are several,
    else the last ``fraction`` of the lone flight's time (no window crosses)."""
    flights = list(dict.fromkeys(f for f, _ in pieces))
    out = []
    if len(flights) > 1:
        k = max(2, int(round(1 / fraction)))
        val = set(validation) if validation else set(flights[k - 1::k] or flights[-1:])
        for f, w in pieces:
            s = full_starts(w, H)
            out.append(Piece(f, w, np.zeros(0, int) if f in val else s[::stride], s if f in val else np.zeros(0, int)))
        return out, {"by": by if validation else "flight", "training": [f for f in flights if f not in val],
                     "validation": [f for f in flights if f in val]}
    t0 = min(w.t[0] for _, w in pieces)
    t1 = max(w.t[-1] for _, w in pieces)
    cut = t1 - fraction * (t1 - t0)
    for f, w in pieces:
        s = full_starts(w, H)
        out.append(Piece(f, w, s[w.t[s + H] < cut][::stride], s[w.t[s] >= cut]))
    return out, {"by": "time", "training": flights, "validation": flights, "validation_from_s": float(cut)}


@dataclass
class Batch:
    """Windows gathered as tensors (B windows, H steps)."""

    X0: object  # (B, 13)
    U: object  # (B, H, 4)
    dt: object  # (B, H)
    truth: tuple  # tp (B, H, 3), tq (B, H, 4), tv (B, H, 3), tw (B, H, 3)

    def __len__(self):
        return self.X0.shape[0]

    def take(self, idx) -> "Batch":
        return Batch(self.X0[idx], self.U[idx], self.dt[idx], tuple(x[idx] for x in self.truth))


def gather(pieces: list[Piece], part: str, H: int, P: np.ndarray, stride: int = 1) -> Batch:
    """The windows of ``part`` (``train`` / ``val``; every ``stride``-th) of every piece as one :class:`Batch`."""
    import torch

    from .rollout_torch import DTYPE

    X0, U, dt, tp, tq, tv, tw = [], [], [], [], [], [], []
    steps = np.arange(1, H + 1)
    for pc in pieces:
        s = getattr(pc, part)[::stride]
        if not len(s):
            continue
        w = pc.windows
        Ud = w.inputs(P)
        j = s[:, None] + steps  # the predicted samples i + h
        X0.append(w.X0[s])
        U.append(Ud[j - 1])  # U[i + h − 1] acts over step h
        dt.append(w.t[j] - w.t[j - 1])
        for acc, arr in ((tp, w.tp), (tq, w.tq), (tv, w.tv), (tw, w.tw)):
            acc.append(arr[j])
    if not X0:
        raise QrInputError(None, f"no full {H}-step window for {'training' if part == 'train' else 'validation'}",
                           "give longer flights, or a shorter learn.horizon")
    t = lambda parts: torch.as_tensor(np.concatenate(parts), dtype=DTYPE)  # noqa: E731
    return Batch(t(X0), t(U), t(dt), (t(tp), t(tq), t(tv), t(tw)))


# ---- the loss ------------------------------------------------------------------------------------

def step_mae(E):
    """MAE per step and signal (H, 4) of errors (B, H, 4) with NaN where the truth is missing, and the
    counts; a step without a window counts 0."""
    import torch

    ok = torch.isfinite(E)
    n = ok.sum(0)
    return torch.where(ok, E, torch.zeros_like(E)).sum(0) / n.clamp(min=1), n


def loss_of(E, weights_h, weights_s, ref):
    """``Σ_s λ_s Σ_h w_h MAE_{s,h} / ref_s`` (tensors: (H,), (4,), (4,))."""
    mae, _ = step_mae(E)
    return (weights_h[:, None] * mae * (weights_s / ref)[None, :]).sum()


def errors(batch: Batch, P, net):
    from .rollout_torch import rollout, window_errors

    return window_errors(rollout(batch.X0, batch.U, batch.dt, P, net), *batch.truth)


# ---- training ------------------------------------------------------------------------------------

@dataclass
class Trained:
    """What training found (the stage writes it out)."""

    net: object  # qr.rollout_torch.ResidualNet, the weights of the best validation loss
    epochs: list[dict]  # per epoch: train_loss, val_loss, seconds
    best_epoch: int
    stopped: str  # why training ended
    reference: dict  # ref_s per signal (rate_frozen's mean MAE over h, training windows)
    initial: dict  # the losses of the vehicle without the residual
    windows: dict  # counts of training and validation windows
    wall_s: float
    skipped_steps: int = 0  # batches whose loss or gradient was not finite (not stepped)
    threads: int = 1  # torch's threads during the epochs (the most seen at an epoch's end)


def _reference(pieces: list[Piece], vehicle, H: int) -> np.ndarray:
    """``ref_s``: rate_frozen's mean MAE over h = 1..H on the training windows (:func:`qr.rollout.reference_mae`)."""
    from .rollout import reference_mae

    ref = reference_mae([pc.windows.scored_at(pc.train) for pc in pieces if len(pc.train)], vehicle, H)
    if not np.all(np.isfinite(ref) & (ref > 0)):
        raise QrInputError(None, "the training windows hold no truth for some signal",
                           "give flights with position, attitude and rotor speeds")
    return ref


def initial_net(cfg: ResidualConfig, vehicle, pieces: list[Piece], seed: int):
    """The network to train: the vehicle's own residual (fine-tuning), else a new one with zero output
    (the physical vehicle at the start) and the inputs' mean and spread over the training starts."""
    import torch

    from .residual import features
    from .rollout_torch import ResidualNet

    if getattr(vehicle, "residual", None) is not None:
        return ResidualNet.from_residual(vehicle.residual), "fine-tuned from the vehicle's residual"
    from .frames import quat_to_rot

    X = np.concatenate([pc.windows.X0[pc.train] for pc in pieces if len(pc.train)])
    U = np.concatenate([pc.windows.U[pc.train] for pc in pieces if len(pc.train)])
    R = quat_to_rot(X[:, X_QUAT] / np.linalg.norm(X[:, X_QUAT], axis=1, keepdims=True))
    v_b = np.einsum("nji,nj->ni", R, X[:, X_VEL])
    speed = float(vehicle.hover_speed)
    phi = features(cfg.inputs, v_b, X[:, X_RATE], -R[:, 2, :], U, speed)
    mean, scale = phi.mean(axis=0), phi.std(axis=0)
    scale = np.where(scale > 1e-9 * np.maximum(1.0, np.abs(mean)), scale, 1.0)
    arm = float(np.mean(np.linalg.norm(vehicle.rotors.positions, axis=1)))
    weight = vehicle.mass * 9.81
    out = np.array([cfg.force_scale * weight] * 3 + [cfg.torque_scale * weight * arm] * 3)
    torch.manual_seed(seed)
    net = ResidualNet(cfg.inputs, cfg.width, cfg.depth, cfg.activation, mean, scale, out, speed)
    with torch.no_grad():  # zero output: training starts from the physical vehicle
        net.layers[-1].weight.zero_()
        net.layers[-1].bias.zero_()
    return net, "new"


def train(cfg: ResidualConfig, vehicle, pieces: list[Piece], seed: int, log=lambda msg: None,
          on_epoch=None, keep_start: bool = True) -> Trained:
    """Train on the pieces' ``train`` starts, stop on their ``val`` starts (see the module doc).
    ``keep_start=False``: the start's weights are never the ones kept (an ensemble member must move)."""
    import copy

    import torch

    from .parallel import torch_one_thread

    threads = torch.get_num_threads()
    deterministic = torch.are_deterministic_algorithms_enabled()
    torch_one_thread(torch)  # small nets: one thread is faster, and the order of every sum is fixed
    torch.use_deterministic_algorithms(True)
    t_start = time.perf_counter()
    try:
        train_b, val_b, ref_np, terms = _windows(cfg, vehicle, pieces)
        net, how = initial_net(cfg, vehicle, pieces, seed)
        log(f"{len(train_b)} training and {len(val_b)} validation windows of {cfg.horizon} steps; network {how}")
        initial = {"train_loss": _loss_on(train_b, net, terms), "val_loss": _loss_on(val_b, net, terms)}
        best, best_state, best_epoch, stale, skipped = initial["val_loss"], copy.deepcopy(net.state_dict()), 0, 0, 0
        if not keep_start:
            best = math.inf
        opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        gen = torch.Generator().manual_seed(seed)
        history, stopped, threads_seen = [], f"the epoch limit ({cfg.epochs})", 1
        clock = time.perf_counter
        for epoch in range(1, cfg.epochs + 1):
            t0 = clock()
            order = torch.randperm(len(train_b), generator=gen)
            train_loss, bad, spent = _epoch(net, opt, train_b, order, cfg, terms, clock)
            skipped += bad
            t5 = clock()
            val = _loss_on(val_b, net, terms)
            spent["validation_s"] = clock() - t5
            history.append({"epoch": epoch, "train_loss": train_loss, "val_loss": val,
                            "seconds": clock() - t0, **spent})
            threads_seen = max(threads_seen, torch.get_num_threads())
            if on_epoch:
                on_epoch(history[-1])
            log(f"epoch {epoch}: training loss {history[-1]['train_loss']:.4f}, validation {val:.4f}")
            if val < best:
                best, best_state, best_epoch, stale = val, copy.deepcopy(net.state_dict()), epoch, 0
            else:
                stale += 1
                if stale >= cfg.patience:
                    stopped = f"no better validation loss for {cfg.patience} epochs"
                    break
        net.load_state_dict(best_state)
        return Trained(net, history, best_epoch, stopped, dict(zip(QUANTITIES, ref_np.tolist())), initial,
                       {"train": len(train_b), "val": len(val_b)}, time.perf_counter() - t_start, skipped,
                       threads_seen)
    finally:
        torch.set_num_threads(threads)
        torch.use_deterministic_algorithms(deterministic)


def _windows(cfg: ResidualConfig, vehicle, pieces: list[Piece]):
    """The training and validation windows (validation on every stride-th start: the final table takes every
    start, compiled), the reference MAE per quantity and the loss's terms (the plant's parameters, the horizon
    and signal weights, the reference as a tensor)."""
    import torch

    from .rollout_torch import DTYPE
    from .sim.plant import true_params

    H = cfg.horizon
    P0 = true_params(vehicle, vehicle.effects, residual=False)
    train_b, val_b = gather(pieces, "train", H, P0), gather(pieces, "val", H, P0, cfg.stride)
    ref_np = _reference(pieces, vehicle, H)
    terms = (torch.as_tensor(P0, dtype=DTYPE), torch.as_tensor(cfg.horizon_weights(), dtype=DTYPE),
             torch.as_tensor(cfg.signal_weights.vector(), dtype=DTYPE), torch.as_tensor(ref_np, dtype=DTYPE))
    return train_b, val_b, ref_np, terms


def _loss_on(batch, net, loss_terms: tuple) -> float:
    """The loss of ``net`` on every window of ``batch`` (in chunks of 2048, no gradient)."""
    import torch

    P, wh, ws, ref = loss_terms
    with torch.no_grad():
        parts = [errors(batch.take(slice(a, a + 2048)), P, net) for a in range(0, len(batch), 2048)]
        return float(loss_of(torch.cat(parts), wh, ws, ref))


def _epoch(net, opt, train_b, order, cfg: ResidualConfig, loss_terms: tuple, clock) -> tuple[float, int, dict]:
    """One pass over the training windows in ``order``, a step per batch (a batch whose loss or gradient is
    not finite is skipped); its mean training loss, the skipped batches and where the time went."""
    import torch

    P, wh, ws, ref = loss_terms
    spent = dict.fromkeys(("gather_s", "forward_s", "backward_s", "validation_s"), 0.0)
    total, n, skipped = 0.0, 0, 0
    for a in range(0, len(order), cfg.batch):
        t1 = clock()
        idx = order[a:a + cfg.batch]
        b = train_b.take(idx)
        t2 = clock()
        loss = loss_of(errors(b, P, net), wh, ws, ref)
        t3 = clock()
        opt.zero_grad()
        loss.backward()
        norm = torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.clip)
        if math.isfinite(loss.item()) and math.isfinite(norm.item()):
            opt.step()
            total += loss.item() * len(idx)
            n += len(idx)
        else:
            skipped += 1
        t4 = clock()
        spent["gather_s"] += t2 - t1
        spent["forward_s"] += t3 - t2
        spent["backward_s"] += t4 - t3  # with the clip and Adam's step
    return total / max(n, 1), skipped, spent


def validation_blocks(pieces: list[Piece], vehicles: dict, H: int) -> dict:
    """The compiled rollout (``qr evaluate``'s) on the validation starts: a :func:`qr.rollout.summary`
    block per model (``vehicles``: name → vehicle; plus ``rate_frozen`` of the first)."""
    from .rollout import pool
    from .sim.plant import true_params

    first = next(iter(vehicles.values()))
    plants = {"rate_frozen": (true_params(first, residual=False), RATE_FROZEN),
              **{k: (true_params(v, v.effects), MODEL) for k, v in vehicles.items()}}
    parts = []
    for pc in pieces:
        if len(pc.val):
            wk = pc.windows.scored_at(pc.val)
            parts.append({k: score_plant(wk, H, P, mode) for k, (P, mode) in plants.items()})
    return {k: summary(*v) for k, v in pool(parts).items()}
