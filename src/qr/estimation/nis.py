"""Filter consistency: normalised innovation squared (NIS) and the innovation likelihood.

For a consistent filter the innovations ``y_k ~ N(0, S_k)`` are white, so
``NIS_k = y_kᵀ S_k⁻¹ y_k ~ χ²(m)`` and the mean of ``n`` of them times ``n`` is
``χ²(n m)``.  A mean outside that distribution's two-sided band flags the
filter: above it the filter is over-confident (noise understated: the
estimates are noisier than their reported ``sd_``), below it under-confident.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np


@dataclass
class Innovations:
    """Per-sample innovation statistics of one filter (NaN where there was no update)."""

    nis: np.ndarray  # (N, c) normalised innovation squared yᵀ S⁻¹ y, one column per channel
    logdet: np.ndarray  # (N, c) log det S
    dof: int  # measurement dimension of one column


def _chi2_ppf(q, k):
    """The chi-square quantile (``scipy.stats.chi2.ppf``) of ``k`` degrees of freedom."""
    from scipy.special import gammaincinv  # chi2.ppf's own kernel: scipy.stats costs a quarter second more

    return 2.0 * gammaincinv(k / 2.0, q)


def nis_stats(nis: np.ndarray, dof: int, confidence: float = 0.95) -> dict:
    """Mean NIS, its χ² band and the verdict for one channel (NaNs ignored)."""
    v = np.asarray(nis, dtype=float)
    v = v[np.isfinite(v)]
    n = int(v.size)
    if n == 0:
        return {"n": 0, "dof": dof, "mean": None, "band": None, "consistent": None, "verdict": "no updates"}
    tail = (1 - confidence) / 2
    lo, hi = _chi2_ppf(np.array([tail, 1 - tail]), n * dof) / n
    slo, shi = _chi2_ppf(np.array([tail, 1 - tail]), dof)
    mean = float(v.mean())
    consistent = bool(lo <= mean <= hi)
    verdict = ("consistent" if consistent else
               "over-confident: NIS too large, noise understated (raise q or r)" if mean > hi else
               "under-confident: NIS too small, noise overstated (lower q or r)")
    return {"n": n, "dof": dof, "mean": mean, "band": [float(lo), float(hi)], "consistent": consistent,
            "verdict": verdict, "outside_sample_band": float(np.mean((v < slo) | (v > shi))),
            "expected_outside": 1 - confidence}


def report(inn: Innovations, names: list[str] | None, keep: np.ndarray, confidence: float) -> dict:
    """NIS statistics of a filter; with several channels (rotors) one entry each plus their pool."""
    nis = np.where(keep[:, None], inn.nis, np.nan)
    if nis.shape[1] == 1:
        return nis_stats(nis[:, 0], inn.dof, confidence)
    out = {name: nis_stats(nis[:, i], inn.dof, confidence) for i, name in enumerate(names)}
    out["all"] = nis_stats(nis.ravel(), inn.dof, confidence)
    return out


@dataclass(frozen=True)
class NisReport:
    """A filtered flight's report, the filter stage's ``<flight>.nis.json`` (:meth:`to_json`, in this order):
    the settings, the noise values used, the tuning record and each filter's NIS (:func:`report`)."""

    filter: str
    implementation: str
    smoother: bool
    discretisation: str
    samples: int
    duration_s: float
    dropouts: Mapping[str, int]  # filter -> samples without its measurement
    noise: Mapping[str, Mapping]  # filter -> q, r (corner_hz with exact discretisation)
    tuning: Mapping[str, Mapping] | None  # filter -> its likelihood-tuned values; None: not tuned
    gyro: Mapping  # fused (and bias, noise_sd, samples if so)
    attitude_restarts: Mapping  # count, t (the first 20)
    nis: Mapping[str, Mapping]  # filter -> :func:`nis_stats` (motor: per rotor and "all")
    nis_burn_in_s: float
    inconsistent: tuple[str, ...]  # the filters (rotors as motor.uN) whose mean NIS is outside its band
    nis_note: str | None
    tuned_on_s: tuple[float, float] | None = None  # the airborne segment the tuned values come from
    flight: str | None = None  # set by the filter stage (qr.estimation.run)
    config: Mapping | None = None

    def to_json(self) -> dict:
        """The ``.nis.json`` document (a field that defaults to None only where set)."""
        doc = {f.name: v for f in fields(self) if (v := getattr(self, f.name)) is not None or f.default is not None}
        return doc | {k: list(doc[k]) for k in ("inconsistent", "tuned_on_s") if k in doc}

    @classmethod
    def from_json(cls, doc: Mapping) -> NisReport:
        """The report of a ``.nis.json`` document (read by :func:`qr.intake.read_reports`)."""
        return cls(**{**doc, **{k: tuple(doc[k]) for k in ("inconsistent", "tuned_on_s") if k in doc}})
