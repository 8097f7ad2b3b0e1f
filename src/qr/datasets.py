"""Learning data: input groups, residual targets, and splits that cannot leak.

One learning table per data set (:func:`build_table`; :func:`features` gives the same columns from a
simulation), the runs' inputs and target from it (:func:`xy`); splits never shuffle across time; runs fed
the label's own input are flagged ``leaks_target``.  The splits and why inputs leak: docs/learn.md "Data and
splits", "Why some inputs leak".
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import numpy as np

from .dynamics import residuals
from .errors import QrInputError
from .frames import rot_to_quat

if TYPE_CHECKING:  # pandas is imported where a table is made or read: the split settings (SPLITS) are read by
    import pandas as pd  # every Hydra command

_XYZ = ("x", "y", "z")
_ROT = ("1", "2", "3", "4")

# group -> component names; order fixes the column order of X
GROUPS: dict[str, tuple[str, ...]] = {
    "v_b": _XYZ,  # body-frame velocity (m/s)
    "a_b": _XYZ,  # body-frame acceleration (m/s^2): leaks f_a
    "p": _XYZ,  # position, world (m)
    "p_z": ("z",),  # height only (thesis Table 4.2, model 1)
    "q": ("w", "x", "y", "z"),  # attitude quaternion, qw >= 0
    "omega": _XYZ,  # body rates (rad/s)
    "alpha": _XYZ,  # body angular acceleration (rad/s^2): leaks tau_a
    "u": _ROT,  # rotor speeds (vehicle unit)
    "u2": _ROT,  # squared rotor speeds (thrust is linear in them)
}
TARGETS: dict[str, tuple[str, ...]] = {"f_a": _XYZ, "tau_a": _XYZ}
TARGET_UNITS = {"f_a": "N", "tau_a": "N m"}
# the input from which the target is computed algebraically
LEAKS = {"f_a": frozenset({"a_b"}), "tau_a": frozenset({"alpha"})}


def columns(groups) -> list[str]:
    """Column names of input groups (or targets) in order: ``['v_b.x', 'v_b.y', ...]``."""
    out = []
    for g in groups:
        comps = GROUPS.get(g) or TARGETS.get(g)
        if comps is None:
            raise _unknown(g, "input group", list(GROUPS))
        out += [f"{g}.{c}" for c in comps]
    return out


def target_columns(target: str) -> list[str]:
    check_target(target)
    return [f"{target}.{c}" for c in TARGETS[target]]


def _unknown(name, what, known):
    import difflib

    close = difflib.get_close_matches(str(name), known, n=1)
    hint = f" (did you mean '{close[0]}'?)" if close else ""
    return QrInputError(None, f"unknown {what} '{name}'{hint}", f"use one of {', '.join(known)}")


def check_inputs(inputs) -> list[str]:
    inputs = [str(g) for g in (inputs or [])]
    if not inputs:
        raise QrInputError(None, "no input groups given", f"set inputs=[...] from {', '.join(GROUPS)}")
    for g in inputs:
        if g not in GROUPS:
            raise _unknown(g, "input group", list(GROUPS))
    if len(set(inputs)) != len(inputs):
        raise QrInputError(None, f"input groups {inputs} repeat a group", "list each group once")
    return inputs


def check_target(target) -> str:
    if target not in TARGETS:
        raise _unknown(target, "target", list(TARGETS))
    return str(target)


def leaks_target(target: str, inputs) -> bool:
    """True when an input group is one the target is computed from algebraically."""
    return bool(LEAKS[check_target(target)] & set(inputs))


def group_values(s, group: str) -> np.ndarray:
    """Values (N, k) of one input group from a :class:`qr.effects.Signals`."""
    if group == "q":
        return rot_to_quat(s.R)
    if group == "p_z":
        return s.p[:, 2:3]
    if group == "u2":
        return s.u**2
    if group in GROUPS:
        return np.asarray(getattr(s, group), dtype=float)
    raise _unknown(group, "input group", list(GROUPS))


def features(signals, inputs) -> np.ndarray:
    """Model input ``X`` (N, d) from a :class:`qr.effects.Signals`; columns as :func:`columns`."""
    return np.hstack([group_values(signals, g) for g in check_inputs(inputs)])


def flight_table(states: pd.DataFrame, vehicle, flight: str) -> pd.DataFrame:
    """Learning-table rows of one filtered flight (a state table, ``qr.states``): its airborne rows.

    On the ground the floor carries the vehicle (``qr.airborne``): a model that learned
    those rows would learn the floor.
    """
    from .airborne import airborne_mask
    from .states import check, signals

    check(states, flight)
    states = states[airborne_mask(states, vehicle)].reset_index(drop=True)
    s = signals(states)
    cols = {"flight": flight, "t": states["t"].to_numpy(dtype=float)}
    for g in GROUPS:
        for name, v in zip(columns([g]), group_values(s, g).T):
            cols[name] = v
    y = residuals(s, vehicle)
    for j, name in enumerate(target_columns("f_a") + target_columns("tau_a")):
        cols[name] = y[:, j]
    import pandas as pd

    df = pd.DataFrame(cols)
    return df[np.isfinite(df.drop(columns="flight").to_numpy()).all(axis=1)].reset_index(drop=True)


def build_table(states: dict, vehicle) -> pd.DataFrame:
    """Learning table of several flights: ``{flight name: state table}``, in the given order."""
    parts = [flight_table(df, vehicle, name) for name, df in states.items()]
    if not parts:
        raise QrInputError(None, "no flights given to build a learning table", "list filtered flights")
    import pandas as pd

    return pd.concat(parts, ignore_index=True)


def write_table(table: pd.DataFrame, path) -> None:
    from .atomic import atomic_path

    with atomic_path(path) as tmp:
        table.to_parquet(tmp, index=False)


DATASET_FIX = ("give learn.dataset=PATH: a learning table (the workflow's results/learn/<set>/dataset.parquet) or "
               "the state table `qr filter` writes (filter.out=PATH) with learn.vehicle=V.yaml")


def check_dataset(path) -> Path:
    """The path of a learning table or state table that exists (one line naming the key otherwise)."""
    path = Path(path)
    if not path.is_file():
        raise QrInputError(path, "learning table does not exist" if not path.exists() else "is not a file",
                           DATASET_FIX)
    return path


def read_table(path, vehicle=None) -> pd.DataFrame:
    """A learning table; or one built from the state table ``qr filter`` writes (labels with ``vehicle``:
    a :class:`qr.vehicle.Vehicle`, a vehicle file or a shipped vehicle's name)."""
    import pandas as pd

    from .states import COLUMNS as STATE_COLUMNS

    path = check_dataset(path)
    try:
        table = pd.read_parquet(path)
    except Exception:  # pyarrow's errors vary: not Parquet, truncated, ...
        raise QrInputError(path, "is not a Parquet table", DATASET_FIX) from None
    need = ["flight", "t", *columns(GROUPS), *target_columns("f_a"), *target_columns("tau_a")]
    missing = [c for c in need if c not in table.columns]
    if missing and all(c in table.columns for c in STATE_COLUMNS):
        if vehicle is None:
            raise QrInputError(path, "is a state table: its labels f_a, tau_a depend on the vehicle",
                               "name it: learn.vehicle=V.yaml (or a shipped vehicle's name)")
        from .flight import check_hover_ratio
        from .vehicle import Vehicle, load_vehicle

        vehicle = vehicle if isinstance(vehicle, Vehicle) else load_vehicle(vehicle)
        check_hover_ratio(table, vehicle, path)  # labels with another vehicle's numbers: refused, not learnt
        return build_table({path.stem: table}, vehicle)
    if missing:
        raise QrInputError(path, f"neither a learning table nor a state table: lacks {missing[:4]}", DATASET_FIX)
    return table


def xy(table: pd.DataFrame, inputs, target: str) -> tuple[np.ndarray, np.ndarray]:
    """``(X, y)`` of a learning table for the given input groups and target."""
    return (table[columns(check_inputs(inputs))].to_numpy(dtype=float),
            table[target_columns(target)].to_numpy(dtype=float))


# --------------------------------------------------------------------------- splits


@dataclass
class Split:
    """Row positions of each part, every part sorted (time order within a flight)."""

    train: np.ndarray
    val: np.ndarray
    test: np.ndarray
    inner_test: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))  # thesis only; unused
    windows: dict = field(default_factory=dict)  # part -> {flight: [t_start, t_end]} (provenance)


def _thirds() -> list[float]:
    return [0.70, 0.15, 0.15]


# the config group ``split``: one structured config per kind (Hydra's ConfigStore, ``schema_<kind>``,
# selected by conf/split/<kind>.yaml), the one place their options and defaults are written
@dataclass
class ThesisSplit:
    kind: str = "thesis"
    flight: Optional[str] = None  # a flight name; null = the flights one after the other, in table order
    start: int = 1500  # first training sample
    train: int = 1500  # training window (samples)
    test: int = 1500  # test window, right after it
    fractions: list[float] = field(default_factory=_thirds)  # the training window cut train/val/inner test


@dataclass
class BlockedSplit:
    kind: str = "blocked"
    fractions: list[float] = field(default_factory=_thirds)  # shares of each flight's duration (after the gaps)
    gap_s: float = 1.0  # seconds left out between blocks (filter smoothing and autocorrelation)


@dataclass
class ByFlightSplit:
    kind: str = "by_flight"
    fractions: list[float] = field(default_factory=_thirds)  # train / validation / test share of the flights
    seed: int = 0  # which flights go where (a permutation of flights, never of samples)
    val_flights: Optional[list[str]] = None  # or explicit lists of flight names (then fractions and seed
    test_flights: Optional[list[str]] = None  # are unused)


SPLITS = {"thesis": ThesisSplit, "blocked": BlockedSplit, "by_flight": ByFlightSplit}
SPLIT_DEFAULTS = {kind: {k: v for k, v in asdict(cls()).items() if k != "kind"} for kind, cls in SPLITS.items()}


def _split_cfg(cfg) -> tuple[str, dict]:
    cfg = dict(cfg or {})
    kind = cfg.pop("kind", None)
    if kind not in SPLIT_DEFAULTS:
        raise _unknown(kind, "split", list(SPLIT_DEFAULTS))
    bad = [k for k in cfg if k not in SPLIT_DEFAULTS[kind]]
    if bad:
        raise QrInputError(None, f"split {kind} has no option(s) {bad}",
                           f"its options are {', '.join(SPLIT_DEFAULTS[kind])}")
    out = {**SPLIT_DEFAULTS[kind], **cfg}
    f = [float(x) for x in out.get("fractions", [1, 0, 0])]
    if len(f) != 3 or min(f) < 0 or f[0] <= 0 or abs(sum(f) - 1) > 1e-6:
        raise QrInputError(None, f"split fractions {f} are not three non-negative parts summing to 1",
                           "write fractions: [train, val, test], e.g. [0.7, 0.15, 0.15]")
    out["fractions"] = f
    return kind, out


def split(table: pd.DataFrame, cfg) -> Split:
    """Train / validation / test rows of a learning table (config group ``split``)."""
    kind, cfg = _split_cfg(cfg)
    sp = {"thesis": _thesis, "blocked": _blocked, "by_flight": _by_flight}[kind](table, cfg)
    for part in ("train", "test"):
        if len(getattr(sp, part)) == 0:
            raise QrInputError(None, f"split {kind} leaves no {part} samples ({len(table)} rows, "
                               f"{table['flight'].nunique()} flight(s))", "use more data or another split")
    sp.windows = {p: _windows(table, getattr(sp, p)) for p in ("train", "val", "test", "inner_test")}
    return sp


def _windows(table, idx) -> dict:
    if len(idx) == 0:
        return {}
    sub = table.iloc[idx]
    g = sub.groupby("flight", sort=False)["t"]
    return {f: [float(a), float(b)] for f, a, b in zip(g.min().index, g.min(), g.max())}


def _thesis(table, cfg) -> Split:
    if cfg["flight"] is not None:
        idx = np.flatnonzero(table["flight"].to_numpy() == str(cfg["flight"]))
        if idx.size == 0:
            raise _unknown(cfg["flight"], "flight", list(table["flight"].unique()))
    else:  # flights in table order, one after the other
        idx = np.arange(len(table))
    start, n_train, n_test = int(cfg["start"]), int(cfg["train"]), int(cfg["test"])
    need = start + n_train + n_test
    if idx.size < need:
        raise QrInputError(None, f"the thesis split needs {need} samples (start {start} + {n_train} train + "
                           f"{n_test} test); the data have {idx.size}",
                           "use split=blocked or split=by_flight, or lower split.start/train/test")
    part = idx[start:start + n_train]
    n_fit = int(round(cfg["fractions"][0] * n_train))
    n_val = int(round(cfg["fractions"][1] * n_train))
    return Split(part[:n_fit], part[n_fit:n_fit + n_val], idx[start + n_train:need], part[n_fit + n_val:])


def _blocked(table, cfg) -> Split:
    gap = float(cfg["gap_s"])
    if gap < 0:
        raise QrInputError(None, f"split gap_s={gap} is negative", "give a gap of at least 1 s")
    f_train, f_val, _ = cfg["fractions"]
    parts = {"train": [], "val": [], "test": []}
    t_all = table["t"].to_numpy()
    for _, idx in table.groupby("flight", sort=False).indices.items():
        idx = np.sort(idx)
        t = t_all[idx]
        gaps = 2 if f_val > 0 else 1
        usable = (t[-1] - t[0]) - gaps * gap
        if usable <= 0:
            continue  # too short to hold every block with its gaps
        a = t[0] + f_train * usable  # train: [t0, a)
        b = a + gap + f_val * usable if f_val > 0 else a  # val: [a + gap, b)
        c = b + gap  # test: [c, end]
        parts["train"].append(idx[t < a])
        if f_val > 0:
            parts["val"].append(idx[(t >= a + gap) & (t < b)])
        parts["test"].append(idx[t >= c])
    cat = {k: np.sort(np.concatenate(v)) if v else np.zeros(0, dtype=int) for k, v in parts.items()}
    return Split(cat["train"], cat["val"], cat["test"])


def _by_flight(table, cfg) -> Split:
    flights = list(dict.fromkeys(table["flight"]))
    if cfg["test_flights"] is not None or cfg["val_flights"] is not None:
        test = [str(f) for f in (cfg["test_flights"] or [])]
        val = [str(f) for f in (cfg["val_flights"] or [])]
        for f in test + val:
            if f not in flights:
                raise _unknown(f, "flight", flights)
        if set(test) & set(val):
            raise QrInputError(None, f"flights {sorted(set(test) & set(val))} are both validation and test",
                               "give disjoint val_flights and test_flights")
    else:
        _, f_val, f_test = cfg["fractions"]
        if len(flights) < 2 + (f_val > 0):
            raise QrInputError(None, f"split by_flight needs at least {2 + (f_val > 0)} flights; "
                               f"the data have {len(flights)}", "use split=blocked for a single flight")
        order = [flights[i] for i in np.random.default_rng(int(cfg["seed"])).permutation(len(flights))]
        n_test = max(1, int(round(f_test * len(flights))))
        n_val = max(1, int(round(f_val * len(flights)))) if f_val > 0 else 0
        test, val = order[:n_test], order[n_test:n_test + n_val]
    name = table["flight"].to_numpy()
    is_test, is_val = np.isin(name, test), np.isin(name, val)
    return Split(np.flatnonzero(~is_test & ~is_val), np.flatnonzero(is_val), np.flatnonzero(is_test))
