"""The training envelope: the states and inputs the training flights covered, and the held-out windows
that leave it (docs/evaluate.md, "Outside the training envelope").

Per quantity (``speed``, ``tilt``, each ``rotor``, each body ``rate``) the extremes over the training flights'
scored windows; a window is *outside* when any of its states or inputs lies beyond them (no threshold).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .plant_state import X_QUAT, X_RATE, X_VEL

QUANTITIES = ("speed", "tilt", "rotor", "rate")
WORDS = {"speed": "speed", "tilt": "tilt", "rotor": "rotor speeds", "rate": "body rates"}


def _tilt(q: np.ndarray) -> np.ndarray:
    """Angle (rad) between the body z axis and the world's vertical, from quaternions (w, x, y, z)."""
    w, x, y, z = q.T
    n = w * w + x * x + y * y + z * z
    r33 = (w * w - x * x - y * y + z * z) / np.where(n > 0, n, np.nan)
    return np.arccos(np.clip(r33, -1.0, 1.0))


def _signals(w) -> dict[str, np.ndarray]:
    """Per sample of a :class:`qr.rollout.Windows`: speed, tilt (n,), rotor speeds (n, 4), body rate (n, 3)."""
    v, q, om = w.X0[:, X_VEL], w.X0[:, X_QUAT], w.X0[:, X_RATE]
    return {"speed": np.linalg.norm(v, axis=1), "tilt": _tilt(q), "rotor": w.U, "rate": om}


def covered(ok: np.ndarray, H: int) -> np.ndarray:
    """Samples j that some scored start i (``ok``) reaches, i ≤ j ≤ i + H."""
    c = np.concatenate([[0], np.cumsum(ok.astype(np.int64))])
    j = np.arange(len(ok))
    return (c[j + 1] - c[np.maximum(j - H, 0)]) > 0


@dataclass(frozen=True)
class Envelope:
    """Extremes of the training flights' states and inputs (see the module's text)."""

    speed_max: float
    tilt_max: float
    rotor_min: tuple[float, ...]
    rotor_max: tuple[float, ...]
    rate_min: tuple[float, float, float]
    rate_max: tuple[float, float, float]
    samples: int

    @classmethod
    def of(cls, windows: list, H: int) -> "Envelope":
        """From the training flights' windows (:class:`qr.rollout.Windows`): every sample an H-step window
        from a scored start covers."""
        parts = [{k: v[covered(w.ok, H)] for k, v in _signals(w).items()} for w in windows]
        parts = [p for p in parts if len(p["speed"])]
        if not parts:
            raise ValueError("no scored sample in the training flights: no envelope")
        s = {k: np.concatenate([p[k] for p in parts]) for k in QUANTITIES}
        return cls(float(np.nanmax(s["speed"])), float(np.nanmax(s["tilt"])),
                   tuple(np.nanmin(s["rotor"], axis=0).tolist()), tuple(np.nanmax(s["rotor"], axis=0).tolist()),
                   tuple(np.nanmin(s["rate"], axis=0).tolist()), tuple(np.nanmax(s["rate"], axis=0).tolist()),
                   int(len(s["speed"])))

    def beyond(self, w) -> dict[str, np.ndarray]:
        """Per sample of ``w``: whether each quantity lies beyond the envelope (NaN is not beyond)."""
        s = _signals(w)
        with np.errstate(invalid="ignore"):
            return {"speed": s["speed"] > self.speed_max, "tilt": s["tilt"] > self.tilt_max,
                    "rotor": ((s["rotor"] < np.array(self.rotor_min)) | (s["rotor"] > np.array(self.rotor_max))).any(1),
                    "rate": ((s["rate"] < np.array(self.rate_min)) | (s["rate"] > np.array(self.rate_max))).any(1)}

    def outside(self, w, H: int) -> dict[str, np.ndarray]:
        """Per scored start of ``w`` (``w.ok``): whether its window leaves the envelope, per quantity and in
        ``any``; states over i … i+H, inputs (the rotor speeds) over i … i+H−1."""
        n = len(w.t)
        idx = np.flatnonzero(w.ok)
        out = {}
        for k, flag in self.beyond(w).items():
            c = np.concatenate([[0], np.cumsum(flag.astype(np.int64))])
            last = np.minimum(idx + (H - 1 if k == "rotor" else H), n - 1)
            out[k] = (c[last + 1] - c[idx]) > 0
        out["any"] = np.any([out[k] for k in QUANTITIES], axis=0) if len(idx) else np.zeros(0, bool)
        return out

    def to_dict(self) -> dict:
        return {"speed_max": self.speed_max, "tilt_max": self.tilt_max, "rotor_min": list(self.rotor_min),
                "rotor_max": list(self.rotor_max), "rate_min": list(self.rate_min), "rate_max": list(self.rate_max),
                "samples": self.samples}


def spans(t: np.ndarray, flag: np.ndarray) -> list[list[float]]:
    """The runs of consecutive flagged starts as ``[t_first, t_last]`` (s)."""
    out, start = [], None
    for k, f in enumerate(flag):
        if f and start is None:
            start = k
        if start is not None and (not f or k == len(flag) - 1):
            end = k if f else k - 1
            out.append([float(t[start]), float(t[end])])
            start = None
    return out


@dataclass(frozen=True)
class Outside:
    """One flight's scored windows against an envelope (:func:`check`)."""

    windows: int  # the scored starts
    outside: int  # those whose window leaves the envelope on any quantity
    share_outside: float | None  # outside / windows (None: no window)
    share_outside_by: Mapping[str, float | None]  # per quantity (QUANTITIES): the share leaving it on that one
    outside_spans_s: tuple[tuple[float, float], ...]  # the start times outside, as spans

    def record(self) -> dict:
        """``evaluation.json``'s ``envelope.per_flight`` entry."""
        return {"windows": self.windows, "outside": self.outside, "share_outside": self.share_outside,
                "share_outside_by": dict(self.share_outside_by),
                "outside_spans_s": [list(s) for s in self.outside_spans_s]}


def check(envelope: Envelope, pieces: list, H: int) -> Outside:
    """One flight's :class:`Outside`: per piece (``qr.rollout.Windows``) the scored starts outside, pooled."""
    total, counts, times = 0, {k: 0 for k in (*QUANTITIES, "any")}, []
    for w in pieces:
        o = envelope.outside(w, H)
        total += int(w.ok.sum())
        for k in counts:
            counts[k] += int(o[k].sum())
        times += spans(w.t[w.ok], o["any"])
    share = {k: (counts[k] / total if total else None) for k in counts}
    return Outside(total, counts["any"], share["any"], {k: share[k] for k in QUANTITIES}, tuple(map(tuple, times)))
