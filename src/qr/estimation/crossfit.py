"""Cross-fitting: labels and regressors from filters that saw disjoint measurements.

The residual label ``f_a = m â - ...`` and many effect designs are built from
the same estimates (``â`` in ``mass_error``, ``α̂`` in ``inertia_error``,
``T(û)`` and ``Γ(û)`` in the label and in ``thrust_gain``...).  Regressing a
label on its own noise "explains" that noise: with one filter, pairs such as
``inertia_error`` + ``yaw_torque_gain`` reproduce a scaled copy of the label and
win cross-validation on pure noise.  So the flight is filtered twice more, once
on the even and once on the odd samples (the others treated as dropouts, with
the noise settings of the full-flight filter): their estimation errors are
independent, and effects are selected and fitted on labels from one half with
regressors from the other (both pairings stacked).  The held-out evaluation uses
the full-flight filter.

This is the filter stage's product: it writes every segment's three estimates to one cross-fit file
(:func:`segment_estimates`, :func:`write_segment_estimates`); :class:`Estimates` is the one reader of
that file (the diagnosis, ``qr evaluate``, ``qr learn residual`` and the learning data set); the intake
(:func:`qr.intake.take`) reads a segment's estimates from it where it has them, else filters them by the
same recipe (:func:`prepare_flight`).
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..atomic import atomic_path
from ..errors import QrInputError
from ..parallel import thread_map
from ..segments import STORED_SPAN_S, flight_segments, min_segment_s
from .matched import add_matched_rotor_signals
from .nis import NisReport
from .pipeline import estimate, tuned_noise
from .settings import resolve
from .tuning import ORDER, corner_hz

MEASURED = ["px", "py", "pz", "qw", "qx", "qy", "qz", "u1", "u2", "u3", "u4"]


def fixed_settings(filter_cfg: dict, tuned: dict | None) -> dict:
    """The filter settings the full flight ended up with (``tuned``: the tuned values, frozen)."""
    cfg = copy.deepcopy(dict(filter_cfg))
    if tuned:
        cfg.setdefault("tune", {})["enabled"] = False
        for f, v in tuned.items():
            cfg.setdefault(f, {})
            cfg[f] = dict(cfg[f], q=v["q"], r=v["r"])
    return cfg


def matched_settings(filter_cfg: dict, tuned: dict | None, bandwidth_factor: float = 1.0) -> dict:
    """Frozen settings with the rotor filters' bandwidth raised to the attitude and position filters'.

    The labels subtract ``T(û)`` from ``m â`` and ``Γ(û)`` from ``J α̂``; a rotor
    filter smoother than the others leaves ``(1 - H) J α`` in the torque label,
    which ``inertia_error`` or ``thrust_gain`` would then "explain".  Rotor speeds
    are measured directly and precisely, so matching costs little noise.
    """
    cfg = resolve(fixed_settings(filter_cfg, tuned))
    q_att = float(np.exp(np.mean(np.log(np.atleast_1d(cfg["attitude"]["q"])))))
    f = min(corner_hz(cfg["position"]["q"], cfg["position"]["r"], ORDER["position"]),
            corner_hz(q_att, cfg["attitude"]["r"], ORDER["attitude"]))
    r_m = cfg["motor"]["r"]
    q_m = r_m * (2 * np.pi * f) ** (2 * ORDER["motor"])
    cfg["motor"]["q"] = max(float(cfg["motor"]["q"]), float(q_m))
    # optionally widen every filter alike: less attenuation (bias) for more noise
    for name in ("position", "attitude", "motor"):
        k = bandwidth_factor ** (2 * ORDER[name])
        q = cfg[name]["q"]
        cfg[name]["q"] = [x * k for x in q] if isinstance(q, list) else q * k
    cfg["tune"]["enabled"] = False
    return cfg


def _half(flight: pd.DataFrame, parity: int) -> pd.DataFrame:
    """The flight with every other sample's measurements removed (dropouts), keeping ``parity``'s."""
    f = flight.copy()
    f.loc[f.index % 2 != parity, MEASURED] = np.nan
    # keep the first rows measured so each filter starts from data
    f.loc[:1, MEASURED] = flight.loc[:1, MEASURED]
    return f


def _states(flight: pd.DataFrame, vehicle, cfg: dict) -> pd.DataFrame:
    st, _ = estimate(flight, vehicle, cfg)
    return add_matched_rotor_signals(st, flight, cfg)


# ---- the filter stage's cross-fit file: every segment's estimates, written once, read by each diagnosis ----

PARTS = ("full", "even", "odd")


def key(filter_cfg: dict, tuned: dict | None, vehicle) -> str:
    """What the estimates depend on: the matched filter settings and the rotor-speed scale."""
    return json.dumps({"filter": matched_settings(filter_cfg, tuned), "hover_speed": float(vehicle.hover_speed)},
                      sort_keys=True, default=str)


def prepare_flight(flight, vehicle, filter_cfg: dict, tuned: dict | None, halves: bool = True):
    """Filtered states for the diagnosis and the cross-fitting halves of one canonical flight.

    ``tuned``: the tuned noise values (:func:`tuned_noise`; a tuning filter's, frozen).  Returns
    ``(states, (even, odd))``; without ``halves`` ``(states, None)`` (a rollout's start states need no
    cross-fitting).
    """
    matched = matched_settings(filter_cfg, tuned)
    # the full flight and its two halves: three independent filters, run side by side
    st, *pair = thread_map(lambda f: _states(f, vehicle, matched),
                           (flight, _half(flight, 0), _half(flight, 1)) if halves else (flight,))
    return st, tuple(pair) if halves else None


def airborne_tuning(flight: pd.DataFrame, vehicle, filter_cfg: dict, progress: bool = False) \
        -> tuple[dict, tuple[float, float]] | None:
    """A tuning filter's (``filter=auto``) noise values and the window they were tuned on (the report's
    ``tuning`` and ``tuned_on_s``), tuned on the flight's longest airborne, gap-free
    segment: ground rows (rotors idle, vehicle resting) would bias the noise values (10 s of them
    moved a hidden kz from 0.044 to 0.095).  The diagnosis on the command line tunes on the same
    rows (:func:`prepare_flight` on its longest segment first), so the filter stage and the command
    line freeze the same values.  None: nothing to tune, no vehicle, or a log that never flew."""
    if vehicle is None or not resolve(filter_cfg)["tune"]["enabled"]:
        return None
    try:
        used = flight_segments(flight, vehicle, 0.0).used
    except QrInputError:  # never airborne: the filter stage tunes on the whole log
        return None
    if not used:
        return None
    seg = max(used, key=lambda s: s.window[1] - s.window[0])  # the first of equals, as sorted() keeps
    return tuned_noise(seg.rows, vehicle, filter_cfg, progress=progress), seg.window


def estimate_segments(used: list, vehicle, filter_cfg: dict, report: NisReport | None, halves: bool = True,
                      stored: "Estimates | None" = None):
    """``(segment, states, halves, source)`` of a flight's ``used`` segments, the longest first (without the
    filter stage's ``report``, a tuning filter is tuned there once): read from ``stored`` (its cross-fit file)
    where it has them, else filtered."""
    tuned, known = (report.tuning, True) if report is not None else (None, False)
    for seg in sorted(used, key=lambda s: s.window[0] - s.window[1]):
        got = stored.get(seg.window[0]) if stored else None
        if got:
            yield seg, got[0], got[1] if halves else None, "read from the filter stage"
        else:
            if not known:
                tuned, known = tuned_noise(seg.rows, vehicle, filter_cfg), True
            st, pair = prepare_flight(seg.rows, vehicle, filter_cfg, tuned, halves)
            yield seg, st, pair, f"filter={filter_cfg.get('name', '?')}"


def segment_estimates(flight: pd.DataFrame, vehicle, filter_cfg: dict, report: NisReport) -> pd.DataFrame:
    """Every airborne, gap-free segment's full estimate and its even/odd halves, stacked
    (``segment_start`` = the segment's first stamp, ``part`` in PARTS): the diagnosis's own recipe
    (:func:`estimate_segments`)."""
    tables = []
    for seg, st, pair, _ in estimate_segments(
            flight_segments(flight, vehicle, min_segment_s(0.0, STORED_SPAN_S)).used, vehicle, filter_cfg, report):
        tables += [table.assign(segment_start=seg.window[0], part=part) for part, table in zip(PARTS, (st, *pair))]
    return pd.concat(tables, ignore_index=True)


@dataclass(frozen=True)
class SegmentEstimate:
    """One airborne, gap-free segment of a flight and its estimates: the full filter's and the
    cross-fitting halves' (each table's ``attrs["flight"]`` is the flight's position: the diagnosis splits
    a flight once, whatever its segments)."""

    flight: int  # the flight's position among a diagnosis's flights
    window: tuple[float, float]  # first and last stamp, the log's own time
    rows: pd.DataFrame  # the measured rows the filters read
    states: pd.DataFrame
    halves: tuple[pd.DataFrame, pd.DataFrame] | None  # (even, odd); None: not asked for (qr.intake)


class Estimates:
    """The filter stage's cross-fit file, its one reader: every segment's full estimate and its even/odd
    halves.  Given the filter settings, the tuned values and the vehicle of a diagnosis, the file is read only
    if it was made with the same matched settings and rotor-speed scale (else :attr:`ok` is False and
    :meth:`get` None: the caller filters)."""

    def __init__(self, path, filter_cfg: dict | None = None, tuned: dict | None = None, vehicle=None):
        import pyarrow.parquet as pq

        if filter_cfg is None:
            self.ok = True
        else:
            meta = pq.read_schema(path).metadata or {}
            self.ok = meta.get(b"qr.crossfit_key", b"").decode() == key(filter_cfg, tuned, vehicle)
        self.table = pd.read_parquet(path) if self.ok else None

    def get(self, start: float):
        """``(full, (even, odd))`` of the segment whose first stamp is ``start``, or None."""
        if not self.ok:
            return None
        rows = self.table[self.table["segment_start"] == start]
        if rows.empty:
            return None
        out = [rows[rows["part"] == p].drop(columns=["segment_start", "part"]).reset_index(drop=True)
               for p in PARTS]
        return out[0], (out[1], out[2])

    def full(self) -> pd.DataFrame:
        """The full-flight ("full") estimates of every segment, in time order: the state table the diagnosis
        builds its labels from (matched settings, matched rotor signals), which the learning data set uses
        too, so both learn the same ``f_a`` and ``tau_a``."""
        full = self.table[self.table["part"] == "full"].drop(columns=["segment_start", "part"])
        return full.sort_values("t", kind="stable").reset_index(drop=True)


def write_segment_estimates(table: pd.DataFrame, out, filter_cfg: dict, tuned: dict | None, vehicle) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    t = pa.Table.from_pandas(table, preserve_index=False)
    t = t.replace_schema_metadata({**(t.schema.metadata or {}), b"qr.crossfit_key": key(filter_cfg, tuned, vehicle).encode()})
    with atomic_path(out, suffix=".parquet") as tmp:
        pq.write_table(t, tmp)
