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


@dataclass(frozen=True)
class NisStats:
    """One channel's NIS over a flight (:func:`nis_stats`): an entry of ``.nis.json``'s ``nis``."""

    n: int  # samples with an update
    dof: int
    mean: float | None  # None: no updates
    band: tuple[float, float] | None  # the mean's two-sided χ²(n·dof)/n band at the confidence
    consistent: bool | None
    verdict: str
    outside_sample_band: float | None = None  # share of samples outside one sample's χ²(dof) band
    expected_outside: float | None = None  # 1 - confidence

    def to_json(self) -> dict:
        doc = {"n": self.n, "dof": self.dof, "mean": self.mean, "band": None if self.band is None else list(self.band),
               "consistent": self.consistent, "verdict": self.verdict}
        if self.n:
            doc |= {"outside_sample_band": self.outside_sample_band, "expected_outside": self.expected_outside}
        return doc

    @classmethod
    def from_json(cls, doc: Mapping) -> NisStats:
        return cls(**{**doc, "band": None if doc["band"] is None else tuple(doc["band"])})


def nis_stats(nis: np.ndarray, dof: int, confidence: float = 0.95) -> NisStats:
    """Mean NIS, its χ² band and the verdict for one channel (NaNs ignored)."""
    v = np.asarray(nis, dtype=float)
    v = v[np.isfinite(v)]
    n = int(v.size)
    if n == 0:
        return NisStats(0, dof, None, None, None, "no updates")
    tail = (1 - confidence) / 2
    lo, hi = _chi2_ppf(np.array([tail, 1 - tail]), n * dof) / n
    slo, shi = _chi2_ppf(np.array([tail, 1 - tail]), dof)
    mean = float(v.mean())
    consistent = bool(lo <= mean <= hi)
    verdict = ("consistent" if consistent else
               "over-confident: NIS too large, noise understated (raise q or r)" if mean > hi else
               "under-confident: NIS too small, noise overstated (lower q or r)")
    return NisStats(n, dof, mean, (float(lo), float(hi)), consistent, verdict,
                    float(np.mean((v < slo) | (v > shi))), 1 - confidence)


@dataclass(frozen=True)
class FilterNis:
    """The NIS of a flight's three filters: ``.nis.json``'s ``nis`` (the rotor filter per rotor and pooled)."""

    position: NisStats
    attitude: NisStats
    motor: Mapping[str, NisStats]  # u1 … u4, then "all"

    @classmethod
    def of(cls, position: Innovations, attitude: Innovations, motor: Innovations, rotors: list[str],
           keep: np.ndarray, confidence: float) -> FilterNis:
        """The statistics of the filters' innovations over the samples ``keep`` (after the burn-in)."""
        def kept(inn):
            return np.where(keep[:, None], inn.nis, np.nan)

        m = kept(motor)
        per_rotor = {name: nis_stats(m[:, i], motor.dof, confidence) for i, name in enumerate(rotors)}
        return cls(nis_stats(kept(position)[:, 0], position.dof, confidence),
                   nis_stats(kept(attitude)[:, 0], attitude.dof, confidence),
                   per_rotor | {"all": nis_stats(m.ravel(), motor.dof, confidence)})

    def channels(self) -> list[tuple[str, NisStats]]:
        """(name, statistics) of every channel, in the document's order: position, attitude, motor.u1 … motor.all."""
        return [("position", self.position), ("attitude", self.attitude),
                *((f"motor.{k}", st) for k, st in self.motor.items())]

    def inconsistent(self) -> tuple[str, ...]:
        """The channels whose mean NIS is outside its band (the rotors each, not their pool)."""
        return tuple(name for name, st in self.channels() if name != "motor.all" and st.consistent is False)

    def to_json(self) -> dict:
        return {"position": self.position.to_json(), "attitude": self.attitude.to_json(),
                "motor": {k: st.to_json() for k, st in self.motor.items()}}

    @classmethod
    def from_json(cls, doc: Mapping) -> FilterNis:
        return cls(NisStats.from_json(doc["position"]), NisStats.from_json(doc["attitude"]),
                   {k: NisStats.from_json(v) for k, v in doc["motor"].items()})


@dataclass(frozen=True)
class NisReport:
    """A filtered flight's report, the filter stage's ``<flight>.nis.json`` (:meth:`to_json`, in this order):
    the settings, the noise values used, the tuning record and each filter's NIS (:class:`FilterNis`)."""

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
    nis: FilterNis
    nis_burn_in_s: float
    inconsistent: tuple[str, ...]  # the filters (rotors as motor.uN) whose mean NIS is outside its band
    nis_note: str | None
    tuned_on_s: tuple[float, float] | None = None  # the airborne segment the tuned values come from
    flight: str | None = None  # set by the filter stage (qr.estimation.run)
    config: Mapping | None = None

    def to_json(self) -> dict:
        """The ``.nis.json`` document (a field that defaults to None only where set)."""
        doc = {f.name: v for f in fields(self) if (v := getattr(self, f.name)) is not None or f.default is not None}
        return doc | {"nis": self.nis.to_json()} | {k: list(doc[k]) for k in ("inconsistent", "tuned_on_s") if k in doc}

    @classmethod
    def from_json(cls, doc: Mapping) -> NisReport:
        """The report of a ``.nis.json`` document (read by :func:`qr.intake.read_reports`)."""
        return cls(**{**doc, "nis": FilterNis.from_json(doc["nis"]),
                      **{k: tuple(doc[k]) for k in ("inconsistent", "tuned_on_s") if k in doc}})
