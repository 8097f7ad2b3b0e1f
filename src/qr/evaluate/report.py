"""``qr evaluate``'s report (:func:`write`: report.md and the figures of an Evaluation): the answer in one
sentence, each model's error as a multiple of the physics baseline's, how the error grows with the horizon,
and the figure.  Every sentence is built from the
numbers it states (``evaluation.json``'s; tests/evaluate/test_evaluate_report.py reads them back)."""

from __future__ import annotations

from pathlib import Path

from ..rollout import QUANTITIES, REFERENCES, at

BASELINE = "rate_frozen"
NAMES = {"p": "position", "v": "velocity", "R": "attitude", "w": "body rate"}
UNITS = {"p": "m", "v": "m/s", "R": "rad", "w": "rad/s"}
# the public nanodrone-sysid-benchmark at h = 50 on its own held-out Crazyflie flights (its table)
PUBLISHED_H50 = {"physics, no drag, rate frozen": {"p": 0.127, "v": 0.578, "R": 0.254, "w": 0.884},
                 "physics + MLP residual": {"p": 0.112, "v": 0.556, "R": 0.231, "w": 0.598}}
FIGURE_CAPTION = ("Mean absolute error against the time ahead, per model (pooled over all windows). Look at each "
                  "solid curve against the dark dashed one, the benchmark's physics baseline (rate_frozen): below "
                  "it the model predicts the flight better; its height at the right end, over the baseline's, is "
                  "the ratio in the table. The grey dashed curve (hold) keeps the state: any model should beat it.")


def labels(doc: dict) -> dict[str, str]:
    """Model key -> the name a report shows (``evaluation.json``'s ``labels``; a reference keeps its own)."""
    return {k: (doc.get("labels") or {}).get(k, k) for k in doc["models"]}


def ratio(models: dict, model: str, q: str, h: int) -> float | None:
    """MAE of ``model`` at step ``h`` over the baseline's (None where either has no window)."""
    x, b = at(models[model], h, q), at(models[BASELINE], h, q)
    return None if x is None or not b else x / b


def _x(r: float | None) -> str:
    return "–" if r is None else f"{r:.3g}"


def _list(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def headline(doc: dict) -> str:
    """The answer: each scored model's error at the horizon as a multiple of the baseline's, and which
    model is lowest on what."""
    H, models, name = doc["horizon"], doc["models"], labels(doc)
    scored = [k for k in models if k not in REFERENCES]
    r = {k: {q: ratio(models, k, q, H) for q in QUANTITIES} for k in scored}
    per_model = "; ".join(f"{name[k]} " + " / ".join(_x(r[k][q]) for q in QUANTITIES) for k in scored)
    s = (f"At h = {H} steps ({H * doc['dt']:.2f} s ahead), each model's error as a multiple of the physics "
         f"baseline's (`{BASELINE}`; below 1 is better), {' / '.join(NAMES[q] for q in QUANTITIES)}: {per_model}")
    if len(scored) > 1:
        lowest: dict[str, list[str]] = {}
        for q in QUANTITIES:
            have = [k for k in scored if r[k][q] is not None]
            if have:
                lowest.setdefault(min(have, key=lambda k: r[k][q]), []).append(NAMES[q])
        s += "; lowest: " + ", ".join(f"{name[k]} on {_list(qs)}" for k, qs in lowest.items())
    better = {k: [NAMES[q] for q in QUANTITIES if r[k][q] is not None and r[k][q] < 1] for k in scored}
    beats = [f"{name[k]} on {_list(qs)}" for k, qs in better.items() if qs]
    s += ("; better than the baseline: " + ", ".join(beats)) if beats else "; no model beats the baseline"
    return s + "."


def _mae(x: float | None, unit: str) -> str:
    return "–" if x is None else f"{x:.3g} {unit}"


def at_horizon_table(doc: dict, models: dict | None = None) -> list[str]:
    """Markdown: MAE at h = H per model and quantity, with its ratio to the baseline."""
    H, models, name = doc["horizon"], models or doc["models"], labels(doc)
    lines = ["| model | " + " | ".join(f"{NAMES[q]} ({UNITS[q]})" for q in QUANTITIES) + " |",
             "|---|" + "---:|" * len(QUANTITIES)]
    for k in models:
        cells = [f"{_mae(at(models[k], H, q), UNITS[q])} ({_x(ratio(models, k, q, H))}×)" for q in QUANTITIES]
        lines.append(f"| {name.get(k, k)} | " + " | ".join(cells) + " |")
    return lines


def growth_table(doc: dict) -> tuple[list[str], list[int]]:
    """Markdown: MAE at h = 1, 10, H and SimErr (the sum over h = 1..H) per model and quantity; the h shown."""
    H, models, name = doc["horizon"], doc["models"], labels(doc)
    hs = sorted({h for h in (1, 10, H) if h <= H})
    fmt = lambda x: "–" if x is None else f"{x:.3g}"  # noqa: E731
    lines = ["| model | " + " | ".join(f"{NAMES[q]} ({UNITS[q]})" for q in QUANTITIES) + " |",
             "|---|" + "---:|" * len(QUANTITIES)]
    for k, block in models.items():
        cells = [" / ".join(fmt(at(block, h, q)) for h in hs) + f" · {fmt(block[q]['simerr'])}" for q in QUANTITIES]
        lines.append(f"| {name[k]} | " + " | ".join(cells) + " |")
    return lines, hs


def per_flight_table(doc: dict) -> list[str]:
    """Markdown: per flight, each scored model's ratios at h = H (position / velocity / attitude / body rate)."""
    H, name = doc["horizon"], labels(doc)
    scored = [k for k in doc["models"] if k not in REFERENCES]
    lines = ["| flight | " + " | ".join(name[k] for k in scored) + " |", "|---|" + "---:|" * len(scored)]
    for f, p in doc["per_flight"].items():
        m = p["models"]
        lines.append(f"| {Path(f).name} | " + " | ".join(" / ".join(_x(ratio(m, k, q, H)) for q in QUANTITIES)
                                                           for k in scored) + " |")
    return lines


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.3g} %"


def split_line(doc: dict) -> list[str]:
    """What the held-out protocol held out (``evaluation.json``'s ``split``), one line; none without it."""
    sp = doc.get("split")
    if not sp:
        return []
    kind = {"repeat": "the scored flights repeat the training flights' trajectories where the set flies each "
                      "several times: interpolation",
            "trajectory": "whole trajectories never trained on", "speed": "faster flights than any trained on: "
                                                                            "extrapolation"}[sp["kind"]]
    return [f"Held out (`evaluate.split.kind={sp['kind']}`): {sp['held_out']}; {len(sp['test'])} flight(s) scored, "
            f"{len(sp['train'])} trained on ({kind}).", ""]


def envelope_section(doc: dict) -> list[str]:
    """Markdown: the windows that leave the training flights' envelope (``evaluation.json``'s ``envelope``)."""
    from ..envelope import QUANTITIES, WORDS

    env = doc.get("envelope")
    if not env:
        return []
    lim, n = env["limits"], len(env["trained_on"])
    by = env["share_outside_by"]
    L = ["## Outside the training envelope", "",
         f"{env['outside']} of {env['windows']} windows ({_pct(env['share_outside'])}) leave the envelope of the "
         f"{n} training flight{'s' * (n > 1)} (a state over the window or an input beyond anything they did): "
         + ", ".join(f"{WORDS[q]} {_pct(by[q])}" for q in QUANTITIES)
         + (". There the models extrapolate." if env["outside"] else "."), "",
         f"The envelope: speed ≤ {lim['speed_max']:.3g} m/s, tilt ≤ {lim['tilt_max']:.3g} rad, rotor speeds "
         + ", ".join(f"{a:.5g}–{b:.5g}" for a, b in zip(lim["rotor_min"], lim["rotor_max"]))
         + ", body rates " + ", ".join(f"{a:.3g}…{b:.3g}" for a, b in zip(lim["rate_min"], lim["rate_max"]))
         + " rad/s (x, y, z).", ""]
    L += ["| flight | windows | outside | " + " | ".join(WORDS[q] for q in QUANTITIES) + " | starts outside (s) |",
          "|---|---:|---:|" + "---:|" * len(QUANTITIES) + "---|"]
    for f, o in env["per_flight"].items():
        spans = o["outside_spans_s"]
        where = ", ".join(f"{a:.2f}–{b:.2f}" for a, b in spans[:4]) + (f" (+{len(spans) - 4})" if len(spans) > 4 else "")
        L.append(f"| {Path(f).name} | {o['windows']} | {_pct(o['share_outside'])} | "
                 + " | ".join(_pct(o["share_outside_by"][q]) for q in QUANTITIES) + f" | {where or '–'} |")
    return L + [""]


def metric_names(doc: dict) -> dict[str, str]:
    """Model key -> its label as an MLflow metric name ("physical (refined)" -> physical_refined)."""
    import re

    return {k: re.sub(r"[^A-Za-z0-9_\-./:]+", "_", v).strip("_") for k, v in labels(doc).items()}


def metrics(doc: dict) -> dict[str, float]:
    """The tracked metrics: MAE at h = H per model and quantity and each model's ratio to ``rate_frozen``,
    named by the models' labels."""
    from ..rollout import horizon_metrics

    name_of = metric_names(doc)
    return horizon_metrics({name_of[k]: v for k, v in doc["models"].items()}, doc["horizon"], ratios=True)


def write(folder: Path, evaluation, figures: bool = True) -> None:
    """``report.md`` of an :class:`qr.evaluate.Evaluation` into ``folder`` and, with ``figures``, its figures
    (``figures/rollout_mae.png``; ``figures/bands.png`` where a model has a band)."""
    from ..atomic import write_text
    from .document import document

    doc, band_fig = document(evaluation), None
    if figures:
        (folder / "figures").mkdir()
        mae_figure(doc, folder / "figures" / "rollout_mae.png")
        if doc.get("bands"):
            from ..report.bands import bands_figure

            band_fig = "figures/bands.png"
            bands_figure(doc, evaluation.bands, folder / band_fig)
    write_text(folder / "report.md", report(doc, "figures/rollout_mae.png" if figures else None, band_fig))


def report(doc: dict, figure: str | None, bands_figure: str | None = None) -> str:
    """``report.md``: ``figure`` is the MAE figure's path relative to the report (None: no figure);
    ``bands_figure``: the bands' (:mod:`qr.report.bands`)."""
    H, n = doc["horizon"], len(doc["flights"])
    lo, hi = doc["dt_range"]
    growth, hs = growth_table(doc)
    L = [f"# Rollout evaluation: {len(doc['models']) - len(REFERENCES)} model(s) on {n} flight{'s' * (n > 1)}", "",
         headline(doc), "", *split_line(doc),
         f"## At the horizon (h = {H}, {H * doc['dt']:.2f} s ahead)", "",
         f"Mean absolute error at h = {H} and, in brackets, its ratio to `{BASELINE}` (the nominal thrust along "
         "body z, no drag, the body rate held: the public nanodrone-sysid-benchmark's physics baseline); `hold` "
         "keeps the state. Attitude: the rotation angle of q⁻¹ ⊗ q̂.", "",
         *at_horizon_table(doc), ""]
    if figure:
        L += [f"![MAE against the time ahead]({figure})", "", f"*{FIGURE_CAPTION}*", ""]
    L += ["## How the error grows", "",
          f"MAE at h = {' / '.join(map(str, hs))} steps · SimErr (the sum over h = 1..{H}). Open-loop rollout from "
          f"every sample of the filtered estimate, step = the log's own ({doc['dt'] * 1e3:.2f} ms; {lo * 1e3:.2f}-"
          f"{hi * 1e3:.2f} ms), driven by the measured rotor speeds; truth: the measured position and attitude, "
          "the estimated velocity and body rate.", "", *growth, ""]
    if len(doc["per_flight"]) > 1:
        scored = [k for k in doc["models"] if k not in REFERENCES]
        L += ["## Per flight", "", f"Ratio to `{BASELINE}` at h = {H}, {' / '.join(NAMES[q] for q in QUANTITIES)}, "
              f"per model ({', '.join(labels(doc)[k] for k in scored)}):", "", *per_flight_table(doc), ""]
    from ..report.bands import bands_section

    L += bands_section(doc, bands_figure)
    L += envelope_section(doc)
    L += ["For comparison, the benchmark's published h = 50 figures on its own held-out Crazyflie flights "
          "(other flights, so only the orders of magnitude compare):", ""]
    L += [f"- {k}: " + ", ".join(f"{NAMES[q]} {v} {UNITS[q]}" for q, v in d.items()) for k, d in PUBLISHED_H50.items()]
    return "\n".join(L) + "\n"


def mae_figure(doc: dict, path: Path) -> None:
    """MAE against the time ahead (h · dt, s), one panel per quantity, one curve per model."""
    import numpy as np

    from ..report import figures

    name, dt = labels(doc), doc["dt"]
    fig, axs = figures.subplots(1, 4, figsize=(13, 3.4), layout="constrained")
    for k, q in enumerate(QUANTITIES):
        for j, (model, block) in enumerate(doc["models"].items()):
            m = np.array([np.nan if x is None else x for x in block[q]["mae"]])
            axs[k].plot(dt * np.arange(1, len(m) + 1), m, label=name[model],
                        color={"hold": "0.6", BASELINE: "0.2"}.get(model, f"C{j}"),
                        ls="--" if model in REFERENCES else "-")
        axs[k].set_xlabel("time ahead (s)")
        axs[k].set_ylim(bottom=0)
        axs[k].set_title(f"{NAMES[q]} ({UNITS[q]})", fontsize=10)
        axs[k].set_ylabel(f"mean absolute error ({UNITS[q]})")
    axs[0].legend(fontsize=7)
    figures.save(fig, path)
