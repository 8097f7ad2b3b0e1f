"""Figures of the filter stage: NIS over a flight, and filtered vs raw like thesis Figs. 4.2–4.8.

"Raw" derivatives are what the thesis set out to avoid: finite differences
of the motion-capture samples (central, on the irregular stamps), and body
rates from consecutive attitudes ``log(q_{k-1}⁻¹ q_{k+1}) / (t_{k+1} - t_{k-1})``.
When the log has a gyro (``gx..gz``, not used by the filters) it is drawn as an
independent check of ω.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import chi2

from ..frames import quat_multiply, rotation
from ..report.figures import save, subplots
from .nis import NisReport

AXES = "xyz"
FIGURES = {  # file stem -> (title, raw columns, filtered columns, unit)
    "position": ("Filtered position p (thesis Fig. 4.2)", ["px", "py", "pz"], "m"),
    "velocity": ("Filtered velocity v (thesis Fig. 4.3)", ["vx", "vy", "vz"], "m/s"),
    "acceleration": ("Filtered acceleration a (thesis Fig. 4.4)", ["ax", "ay", "az"], "m/s²"),
    "quaternion": ("Filtered quaternion q (thesis Fig. 4.5)", ["qw", "qx", "qy", "qz"], "dimensionless"),
    "angular_velocity": ("Filtered angular velocity ω, body (thesis Fig. 4.6)", ["wx", "wy", "wz"], "rad/s"),
    "angular_acceleration": ("Filtered angular acceleration α, body (thesis Fig. 4.7)", ["alx", "aly", "alz"],
                             "rad/s²"),
    "rotors": ("Filtered rotor speeds u (thesis Fig. 4.8)", ["u1", "u2", "u3", "u4"], None),  # the vehicle's
}


def _gradient(t, y):
    return np.gradient(y, t, axis=0)


def raw_derivatives(flight: pd.DataFrame) -> pd.DataFrame:
    """Finite-difference v, a (world) and ω, α (body) of the measurements, NaN around dropouts."""
    t = flight["t"].to_numpy()
    p = flight[["px", "py", "pz"]].to_numpy(dtype=float)
    q = flight[["qw", "qx", "qy", "qz"]].to_numpy(dtype=float)
    v = _gradient(t, p)
    a = _gradient(t, v)
    w = np.full((len(t), 3), np.nan)
    dq = quat_multiply(q[:-2] * np.array([1.0, -1, -1, -1]), q[2:])
    ok = np.all(np.isfinite(dq), axis=1)
    rv = np.full((len(dq), 3), np.nan)
    rv[ok] = rotation(dq[ok]).as_rotvec()
    w[1:-1] = rv / (t[2:] - t[:-2])[:, None]
    al = _gradient(t, w)
    out = pd.DataFrame({"t": t})
    for name, arr in (("v", v), ("a", a), ("w", w), ("al", al)):
        for i, ax in enumerate(AXES):
            out[f"{name}{ax}"] = arr[:, i]
    for c in ["px", "py", "pz", "qw", "qx", "qy", "qz", "u1", "u2", "u3", "u4"]:
        out[c] = flight[c].to_numpy(dtype=float)
    return out


def filtered_vs_raw(flight: pd.DataFrame, states: pd.DataFrame, outdir: str | Path, title: str = "",
                    rotor_unit: str | None = None) -> list[Path]:
    """One PNG per quantity (thesis Figs. 4.2–4.8) into ``outdir/filter_<quantity>.png``; ``rotor_unit``: the
    vehicle file's ``rotor_speed_unit`` (unknown: the axis says so)."""
    from ..rotors import SPEED_UNIT_NAMES

    raw = raw_derivatives(flight)
    t = states["t"].to_numpy() - states["t"].iloc[0]
    paths = []
    for stem, (fig_title, cols, unit) in FIGURES.items():
        fig, axes = subplots(len(cols), 1, figsize=(8, 1.6 * len(cols) + 0.6), sharex=True)
        for ax, c in zip(axes, cols):
            derived = stem not in ("position", "quaternion", "rotors")
            ax.plot(t, raw[c], ".", ms=1.5, color="0.6", label="raw (finite differences)" if derived else "raw")
            if stem == "angular_velocity" and f"g{c[1]}" in flight.columns:
                ax.plot(t, flight[f"g{c[1]}"], lw=0.6, color="tab:green", alpha=0.8, label="gyro (not filtered)")
            ax.plot(t, states[c], lw=1.0, color="tab:blue", label="filtered")
            if f"sd_{c}" in states.columns:
                lo, hi = states[c] - 2 * states[f"sd_{c}"], states[c] + 2 * states[f"sd_{c}"]
                ax.fill_between(t, lo, hi, color="tab:blue", alpha=0.2, lw=0, label="±2 sd")
            finite = states[c].to_numpy()
            span = np.nanmax(finite) - np.nanmin(finite)
            pad = 0.6 * span + 1e-9
            ax.set_ylim(np.nanmin(finite) - pad, np.nanmax(finite) + pad)  # raw noise may be 100x the signal
            ax.set_ylabel(f"{c} ({unit or SPEED_UNIT_NAMES.get(rotor_unit, 'rotor_speed_unit of the vehicle file')})")
        axes[0].legend(loc="upper right", fontsize=7, ncol=4)
        axes[0].set_title(f"{fig_title}{' — ' + title if title else ''}")
        axes[-1].set_xlabel("t (s)")
        path = Path(outdir) / f"filter_{stem}.png"
        save(fig, path)
        paths.append(path)
    return paths


def nis_figure(states: pd.DataFrame, report: NisReport, path: str | Path, title: str = "") -> None:
    """Per-sample NIS of the three filters against the χ² band, with the mean's verdict."""
    t = states["t"].to_numpy() - states["t"].iloc[0]
    conf = 0.95
    panels = [("position", ["nis_p"], 3, report.nis.position), ("attitude", ["nis_q"], 3, report.nis.attitude),
              ("rotors", [f"nis_u{i}" for i in range(1, 5)], 1, report.nis.motor["all"])]
    fig, axes = subplots(3, 1, figsize=(8, 6.5), sharex=True)
    for ax, (name, cols, dof, stats) in zip(axes, panels):
        for c in cols:
            ax.semilogy(t, states[c], ".", ms=1.5, alpha=0.6, label=c if len(cols) > 1 else None)
        lo, hi = chi2.ppf([(1 - conf) / 2, (1 + conf) / 2], dof)
        ax.axhline(dof, color="k", lw=0.8)
        ax.axhspan(lo, hi, color="tab:green", alpha=0.12, lw=0)
        mean = stats.mean
        ax.set_title(f"{name}: mean NIS {mean:.3g} (χ²({dof}) expects {dof}; band of the mean "
                     f"{stats.band[0]:.3g}–{stats.band[1]:.3g}) — {stats.verdict}" if mean is not None else name,
                     fontsize=8)
        ax.set_ylabel("NIS (dimensionless)")
        if len(cols) > 1:
            ax.legend(fontsize=7, ncol=4, loc="upper right")
    axes[-1].set_xlabel("t (s)")
    fig.suptitle(f"Innovation consistency{' — ' + title if title else ''} (filter={report.filter})", fontsize=9)
    save(fig, path)
