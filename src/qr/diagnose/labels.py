"""The residual labels a diagnosis fits: every segment's state table stacked, split, cut in blocks.

The first step of :func:`qr.diagnose.run`.  Each segment's estimates give the nominal model's residual
force and torque (``f_a``, ``tau_a``: :func:`qr.dynamics.residuals`), their noise floor
(:mod:`.noise`) and the signals the effects' designs read.  Two sets are stacked: the full-flight
estimates' (the held-out checks, the replay, the figures) and the cross-fitting halves' (labels of one
half-sample filter, regressors of the other: the fit and the selection; :mod:`qr.estimation.crossfit`),
whose label differences calibrate the noise floor of both.  A :class:`Prepared` set never changes:
where the named delay changes what the designs read, a new one is made (:meth:`Prepared.at_delay`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ..dynamics import residuals
from ..effects import Signals, total_term
from ..identification import delay as delay_mod
from ..parallel import thread_map
from ..states import signals
from ..torque_remainder import torque as remainder_torque
from .noise import calibrate, noise_sd
from .settings import DiagnoseConfig


@dataclass(frozen=True)
class Prepared:
    """All segments stacked: signals, residual labels, noise, and where each sample belongs."""

    s: Signals
    y: np.ndarray  # (N, 6)
    sd: np.ndarray  # (N, 6)
    t: np.ndarray
    flight: np.ndarray  # per sample: index of its state table (a flight, or a segment of one)
    train: np.ndarray  # bool
    test: np.ndarray  # bool
    block: np.ndarray  # block id per training sample (-1 elsewhere)
    windows: list[dict]  # per flight: train/test windows in the flight's own time
    # What effect designs read: ``s`` with the rotor signals delayed by the actuator-delay estimate
    # and the delay's design column (:meth:`at_delay`); None: ``s`` itself.  Labels never change.
    ds: Signals | None = None
    # cross-fitting data: row i + pair_offset is row i's stamp with the other half's label and regressors
    pair_offset: int = 0
    # the rotor signals the labels themselves were built from (cross-fitting: the label's own half); the
    # exact delay term is a transform of the label, not a regressor: W(u(t - d)) - W(u(t)) from the same
    # measurements leaves rotor noise of the same size whatever d, so the delay search is unbiased
    own_u2: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def design_s(self) -> Signals:
        return self.s if self.ds is None else self.ds

    def at_delay(self, vehicle, d: float, shift: float | None = None) -> Prepared:
        """The same labels, the designs reading the rotor map ``d`` late (:func:`at_delay`)."""
        return replace(self, ds=at_delay(self, vehicle, d, shift=shift))


def flight_of(states_list: list[pd.DataFrame]) -> list[int]:
    """The flight each state table belongs to: ``attrs["flight"]`` for a segment of one, else its position."""
    return [int(st.attrs.get("flight", i)) for i, st in enumerate(states_list)]


def _cut(spans: list[tuple[float, float]], fraction: float) -> float:
    """The time at which ``fraction`` of the segments' summed duration lies before it (inside a segment)."""
    target, acc = fraction * sum(b - a for a, b in spans), 0.0
    for a, b in spans:
        if acc + (b - a) >= target:
            return a + (target - acc)
        acc += b - a
    return spans[-1][1]


def _split(states_list: list[pd.DataFrame], cfg: DiagnoseConfig):
    """Per table the rows kept (``trim_s`` off both ends); per flight its train/test cut and windows."""
    owner = flight_of(states_list)
    keeps = []
    for st in states_list:
        t = st["t"].to_numpy()
        keeps.append((t >= t[0] + cfg.trim_s) & (t <= t[-1] - cfg.trim_s))
    cuts, windows = {}, []
    for f in sorted(set(owner)):
        spans = [(st["t"].to_numpy()[k][0], st["t"].to_numpy()[k][-1])
                 for st, k, o in zip(states_list, keeps, owner) if o == f and k.any()]
        if not spans:
            raise ValueError(f"flight {f}: no sample left after trimming trim_s={cfg.trim_s} s at each end")
        cut = cuts[f] = _cut(spans, cfg.train_fraction)
        windows.append({"train": [float(spans[0][0]), float(cut - cfg.gap_s / 2)],
                        "test": [float(cut + cfg.gap_s / 2), float(spans[-1][1])]})
    return owner, keeps, cuts, windows


def prepare(states_list: list[pd.DataFrame], vehicle, cfg: DiagnoseConfig) -> Prepared:
    """Stack state tables: each is trimmed by ``trim_s`` at both ends (filter transients), cut in blocks.

    A table with ``attrs["flight"]`` is one gap-free segment of that flight (``qr.segments``):
    each flight is split once, at ``train_fraction`` of its segments' summed (trimmed) time,
    with ``gap_s`` between its training and test samples; a block never spans two segments.
    """
    owner, keeps, cuts, windows = _split(states_list, cfg)
    parts, blocks_next = [], 0
    for i, (st, keep) in enumerate(zip(states_list, keeps)):
        if not keep.any():
            continue
        st = st[keep].reset_index(drop=True)
        t = st["t"].to_numpy()
        s = signals(st)
        y = residuals(s, vehicle)
        if vehicle.effects:  # an extended vehicle: diagnose what its effects leave
            y = y - total_term(vehicle.effects, s, vehicle)
        y[:, 3:6] -= remainder_torque(vehicle, s.v_b, s.omega, s.u)  # and its learned remainder
        sd = noise_sd(st, s.R, vehicle, y)
        cut = cuts[owner[i]]
        train = t < cut - cfg.gap_s / 2
        test = t >= cut + cfg.gap_s / 2
        block = np.full(len(t), -1)
        rel = t[train] - t[0]
        block[train] = blocks_next + (rel // cfg.block_s).astype(int)
        if train.any():
            used = np.unique(block[train])
            remap = {b: blocks_next + j for j, b in enumerate(used)}
            block[train] = [remap[b] for b in block[train]]
            blocks_next += len(used)
        parts.append((s, y, sd, t, np.full(len(t), i), train, test, block))
    cat = lambda k: np.concatenate([p[k] for p in parts])  # noqa: E731
    s_all = Signals.concat([p[0] for p in parts])
    return Prepared(s_all, cat(1), cat(2), cat(3), cat(4), cat(5), cat(6), cat(7), windows)


def prepare_cross(pairs: list[tuple[pd.DataFrame, pd.DataFrame]], vehicle, cfg: DiagnoseConfig) -> Prepared:
    """Fitting data from disjoint-measurement filters: labels of one half, regressors of the other."""
    a = prepare([p[0] for p in pairs], vehicle, cfg)
    b = prepare([p[1] for p in pairs], vehicle, cfg)
    s = Signals.concat([b.s, a.s])
    cat = lambda k: np.concatenate([getattr(a, k), getattr(b, k)])  # noqa: E731
    return Prepared(s, cat("y"), cat("sd"), cat("t"), cat("flight"), cat("train"), cat("test"), cat("block"),
                    a.windows, pair_offset=len(a.t),
                    own_u2=(np.concatenate([a.s.u2_force, b.s.u2_force]), np.concatenate([a.s.u2_torque, b.s.u2_torque])))


def weights(sd: np.ndarray) -> np.ndarray:
    floor = 1e-3 * np.nanmedian(sd, axis=0)
    return 1.0 / np.maximum(sd, floor) ** 2


def exact_delay_term(prep: Prepared, vehicle, d: float, rows: np.ndarray | None = None) -> np.ndarray:
    """Residual of a rotor map acting ``d`` late: ``W(u(t - d)) - W(u(t))`` on f_z and τ (N, 6; or
    ``rows``)."""
    u2f, u2t = prep.own_u2 or (prep.s.u2_force, prep.s.u2_torque)
    return delay_mod.exact_term(prep.t, prep.flight, u2f, u2t, vehicle.rotors.matrix, d, rows)


def at_delay(prep: Prepared, vehicle, d: float, column: str = "secant", shift: float | None = None) -> Signals:
    """``prep.s`` as effect designs read it when the rotor map acts ``d`` late: rotor signals ``shift``
    (default ``d``) late, and actuator_delay's column (the secant through 0 and ``d``, at least one
    sample; or the tangent at ``d``)."""
    shift = d if shift is None else shift
    args = (prep.t, prep.flight, prep.s.u2_force, prep.s.u2_torque, vehicle.rotors.matrix)
    dt = float(np.median(np.diff(prep.t[:1000]))) if len(prep.t) > 1 else 0.01
    if column == "secant":
        col = delay_mod.secant_column(*args, max(d, dt))
    else:
        col = delay_mod.tangent_column(*args, d, step=0.5 * dt)
    shifted = lambda x: delay_mod.shift(prep.t, prep.flight, x, shift)  # noqa: E731
    return replace(prep.s, u2f=shifted(prep.s.u2_force), u2t=shifted(prep.s.u2_torque), u2f_dot=None, u2t_dot=None,
                   delay_column=col)


@dataclass(frozen=True)
class Labels:
    """The labels of one diagnosis: the full-flight estimates' (``full``: held-out checks, replay, figures)
    and the cross-fitting halves' (``cross``: fit and selection), the noise floor of both calibrated on
    the halves (``noise_scale``, per axis)."""

    full: Prepared
    cross: Prepared
    noise_scale: list[float]

    def at_delay(self, vehicle, d: float, shift: float | None = None) -> Labels:
        """Both sets' designs reading the rotor map ``d`` late."""
        return replace(self, full=self.full.at_delay(vehicle, d, shift), cross=self.cross.at_delay(vehicle, d, shift))


def make_labels(states: list[pd.DataFrame], halves: list[tuple[pd.DataFrame, pd.DataFrame]], vehicle,
                cfg: DiagnoseConfig, on_full=None) -> Labels:
    """The labels of the full-flight estimates ``states`` and of the cross-fitting ``halves``, made side by
    side; ``on_full(prep)``: called with the full set's nominal residuals as soon as they exist."""
    full, cross = thread_map(lambda f: f(), (lambda: prepare(states, vehicle, cfg),
                                             lambda: prepare_cross(halves, vehicle, cfg)))
    if on_full is not None:  # after the threads: a fork beside a running thread could inherit its locks
        on_full(full)
    scale = calibrate(cross)
    return Labels(replace(full, sd=full.sd * scale), replace(cross, sd=cross.sd * scale), scale)
