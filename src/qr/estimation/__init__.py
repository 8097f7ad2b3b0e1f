"""State estimation: from noisy motion capture and rotor speeds to smooth states and derivatives.

One entry point, :func:`estimate`: a canonical flight in, the state table
(:mod:`qr.states`) and a report out.  Three filters (thesis §4.2.1):

- position: linear KF on ``[p, v, a, j]`` (:mod:`.position_kf`);
- attitude: ESKF on SO(3) with ``[q, ω, α, α̇]`` (:mod:`.attitude_eskf`), the log's gyro fused where
  ``attitude.gyro`` is on (:mod:`.gyro`);
- rotors: one KF per rotor on ``[u, u̇, ü]`` (:mod:`.motor_kf`);

with an optional RTS smoother (:mod:`.smoother`), likelihood tuning
(:mod:`.tuning`), NIS consistency (:mod:`.nis`), a filterpy reference path and
a compiled fast path (:mod:`.fast`) that agree to 1e-9.
"""

from __future__ import annotations

from .settings import DEFAULTS, resolve

__all__ = ["estimate", "tuned_noise", "DEFAULTS", "resolve"]


def __getattr__(name: str):
    """:func:`estimate` and :func:`tuned_noise` (:mod:`.pipeline`), imported when first asked for: every Hydra
    command reads this package's settings (the ``filter`` group) and should not pay for pandas and scipy."""
    if name in ("estimate", "tuned_noise"):
        from . import pipeline

        return getattr(pipeline, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
