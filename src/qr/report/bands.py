"""The evaluate report's uncertainty bands (:mod:`qr.bands`): the section of ``report.md`` and its figure."""

from __future__ import annotations

from pathlib import Path

from ..bands import level_scales
from ..rollout import QUANTITIES

NAMES = {"p": "position", "v": "velocity", "R": "attitude", "w": "body rate"}
UNITS = {"p": "m", "v": "m/s", "R": "rad", "w": "rad/s"}
GOAL = (0.80, 0.97)  # issue 33: the 90 % band covers 80-97 % of the held-out samples at h = 50


def _pct(x) -> str:
    return "–" if x is None else f"{100 * x:.0f} %"


def _label(doc: dict, key: str) -> str:
    return (doc.get("labels") or {}).get(key, key)


def caption(doc: dict) -> str:
    H = doc["horizon"]
    return (f"The error of each banded model's prediction h = {H} steps ({H * doc['dt']:.2f} s) ahead, at the time "
            "predicted, over the first scored flight (line), and its 50 % (dark) and 90 % (light) bands: the "
            "scaled radii within which the truth should lie; where the line leaves the light band the truth lies "
            "outside the 90 % band. Position (m) and attitude (rad).")


def bands_section(doc: dict, figure: str | None) -> list[str]:
    """Markdown: each model's band, how it was drawn and scaled, and its coverage at h = H (``bands``)."""
    bands, none = doc.get("bands"), doc.get("bands_none") or {}
    if bands is None:
        return []
    H = doc["horizon"]
    L = ["## How far to trust a rollout: uncertainty bands", ""]
    if not bands:
        L += ["No model carries a band: " + "; ".join(f"{_label(doc, k)}: {why}" for k, why in none.items()) + ".",
              ""]
        return L
    L += [f"Around each banded model's prediction, the 50 % and 90 % bands at h = {H}: balls whose radius is the "
          "spread of an ensemble of plants flown on the same windows (the 50 % and 90 % quantiles of their distance "
          "from the model's prediction) times a scale per quantity and level, chosen on the training side's "
          "validation data so that each band covers its share there (never on these flights). Coverage: the share "
          "of scored samples "
          f"at h = {H} whose truth lies inside (nominally 50 % and 90 %).", "",
          "| model | band from | 90 % scale p / v / R / ω | 90 % band covers p / v / R / ω | 50 % band covers p / v / R / ω "
          "| median 90 % radius p (m) / R (rad) |", "|---|---|---|---|---|---|"]
    for key, b in bands.items():
        by = b["by_quantity"]
        src = (f"{b['draws']} residual members" if b["kind"] == "ensemble" else
               f"{b['draws']} draws of {len(b['parameters'] or [])} parameters")
        scale = " / ".join("–" if (b["scale"] or {}).get(q) is None else f"{b['scale'][q]:.3g}" for q in QUANTITIES)
        c90 = " / ".join(_pct(by[q]["coverage90"]) for q in QUANTITIES)
        c50 = " / ".join(_pct(by[q]["coverage50"]) for q in QUANTITIES)
        rad = " / ".join("–" if by[q]["median_radius90"] is None else f"{by[q]['median_radius90']:.3g}" for q in ("p", "R"))
        L.append(f"| {_label(doc, key)} | {src} | {scale} | {c90} | {c50} | {rad} |")
    L.append("")
    for key, b in bands.items():
        c = b["coverage90"]
        if c is None:
            continue
        lo, hi = GOAL
        verdict = ("within" if lo <= c <= hi else ("below" if c < lo else "above")) + f" the goal's {lo:.0%}-{hi:.0%}"
        unscaled = [q for q in QUANTITIES if (b["scale"] or {}).get(q) is None]
        L.append(f"- {_label(doc, key)}: the 90 % band covers {_pct(c)} of the samples (mean over p, v, R, ω), "
                 f"{verdict}; the 50 % band {_pct(b['coverage50'])}. "
                 + (f"Its spread was multiplied by {max(b['scale'][q] for q in QUANTITIES if b['scale'].get(q)):.3g} at most "
                    "to cover 90 % of the validation samples: the raw ensemble is that much too narrow. "
                    if len(unscaled) < len(QUANTITIES) else "")
                 + (f"Not scaled ({', '.join(unscaled)}): no validation data, the raw spread is shown. " if unscaled else "")
                 + f"Source: {b['source']}.")
    for key, why in none.items():
        L.append(f"- {_label(doc, key)}: no band ({why}).")
    L.append("")
    if figure:
        L += [f"![bands]({figure})", "", f"*{caption(doc)}*", ""]
    return L


def bands_figure(doc: dict, bands, path: Path) -> None:
    """Per banded model (rows), position and attitude (columns): over the first scored flight, the error at h = H
    at the time predicted, with the scaled 50 % and 90 % radii shaded from 0."""
    import numpy as np

    from . import figures

    keys = list(doc["bands"])
    flight = doc["flights"][0]
    H, dt = doc["horizon"], doc["dt"]
    fig, axs = figures.subplots(len(keys), 2, figsize=(11, 2.6 * len(keys) + 0.4), layout="constrained",
                                squeeze=False)
    for r, key in enumerate(keys):
        sp = bands.spread_of(key, flight)
        block = doc["bands"][key]
        for c, q in enumerate(("p", "R")):
            ax = axs[r][c]
            k = QUANTITIES.index(q)
            s, s50 = level_scales(block["scale"], block.get("scale50"), q)
            t = sp.t + H * dt
            for piece in np.unique(sp.piece):  # no line across a gap between pieces
                m = sp.piece == piece
                ax.fill_between(t[m], 0, s * sp.r90[m, k], color="C0", alpha=0.25, lw=0,
                                label="90 % band" if piece == sp.piece[0] else None)
                ax.fill_between(t[m], 0, s50 * sp.r50[m, k], color="C0", alpha=0.5, lw=0,
                                label="50 % band" if piece == sp.piece[0] else None)
                ax.plot(t[m], sp.err[m, k], color="k", lw=0.7, label="error" if piece == sp.piece[0] else None)
            ax.set_ylim(bottom=0)
            ax.set_xlabel("time (s)")
            ax.set_ylabel(f"{NAMES[q]} error at h = {H} ({UNITS[q]})")
            ax.set_title(f"{_label(doc, key)}: {NAMES[q]}", fontsize=9)
        axs[r][0].legend(fontsize=7, loc="upper right")
    figures.save(fig, path)
