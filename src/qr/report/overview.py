"""The workflow's overview page: the answer in one sentence, what was diagnosed, the named effects in a
reader's words with their units, the held-out gains, the rollout, the thesis tables and the main
figures, each with a caption saying what to look at.  One self-contained HTML file (figures inlined),
generated from the workflow's own tables: every sentence is built from the numbers it states
(:func:`set_sentence`, :func:`answer`; tests/workflow/test_overview.py reads them back).
"""

from __future__ import annotations

import base64
import html
import math
import re
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from ..atomic import atomic_path

# a residual within this many times the noise floor (RMSE, on every axis) is "up to noise"
UP_TO_NOISE = 1.5
AXES = ("x", "y", "z")
QUANTITY = {"p": "position", "v": "velocity", "R": "attitude", "w": "body rate"}

# (selector, rules): the page's style, and the same scoped to ``.qr-overview`` for the fragment that
# Snakemake's report shows as its landing page (a bare ``body``/``table`` rule would restyle the report app).
# Tables wrap their cells instead of scrolling sideways.
_RULES = [
    ("body", "font-family: system-ui, sans-serif; max-width: 1100px; margin: 1.5em auto; padding: 0 1em; "
             "color: #222; line-height: 1.45;"),
    ("h1", "font-size: 1.6em;"), ("h2", "font-size: 1.25em; margin-top: 1.8em; border-bottom: 1px solid #ccc;"),
    ("p.answer", "font-size: 1.12em; background: #f4f8fc; border-left: 4px solid #3a78b5; padding: 0.6em 0.9em;"),
    ("table", "border-collapse: collapse; font-size: 0.85em; margin: 0.6em 0; max-width: 100%;"),
    ("th, td", "border: 1px solid #ddd; padding: 3px 7px; text-align: right; vertical-align: top; "
               "overflow-wrap: break-word;"),
    ("th", "background: #f3f3f3;"), ("td:first-child, th:first-child", "text-align: left; white-space: nowrap;"),
    ("caption, figcaption", "caption-side: top; text-align: left; font-size: 0.9em; color: #444; margin: 0.3em 0;"),
    ("figure", "margin: 1.2em 0;"), ("img", "max-width: 100%; box-sizing: border-box; border: 1px solid #eee;"),
    ("ul.effects li", "margin: 0.25em 0;"), (".muted", "color: #666; font-size: 0.9em;"),
]


def _style(scope: str = "") -> str:
    def sel(s):
        if not scope:
            return s
        return ", ".join(scope if x.strip() == "body" else f"{scope} {x.strip()}" for x in s.split(","))

    return "\n".join(f"{sel(s)} {{ {r} }}" for s, r in _RULES)


STYLE = _style()
# Snakemake's landing page centres its content in a fixed-height box (a description taller or wider
# than the screen loses its top and left, unreachable by scrolling), caps it at max-w-lg and wraps code
# in backticks (tailwind prose): undone for the box that holds the overview only
LANDING = ("div.items-center:has(.qr-overview) { align-items: flex-start; justify-content: flex-start; }\n"
           ".max-w-lg:has(.qr-overview) { max-width: 900px; }\n"
           ".qr-overview code::before, .qr-overview code::after { content: none; }")


# ---- the numbers of one diagnosed set (a row of results/tables/diagnosis_summary.csv) ----

@dataclass(frozen=True)
class SetResult:
    name: str
    flights: int
    samples: int
    effects: list[tuple[str, dict[str, float]]]  # named effects and their parameters
    nominal: list[float]  # held-out force RMSE x, y, z (N)
    extended: list[float]
    noise: list[float]
    nominal_torque: list[float]  # N m
    extended_torque: list[float]
    replay: tuple[float, float]  # open-loop replay drift (m): nominal, extended

    @classmethod
    def from_row(cls, row) -> "SetResult":
        return cls(str(row["set"]), int(row["flights"]), int(row["samples"]), parse_named(row.get("named")),
                   _axes(row.get("nominal_force_rmse")), _axes(row.get("extended_force_rmse")),
                   _axes(row.get("noise_force_rmse")), _axes(row.get("nominal_torque_rmse")),
                   _axes(row.get("extended_torque_rmse")),
                   (_num(row.get("replay_nominal_m")), _num(row.get("replay_extended_m"))))

    def over_noise(self, which: str) -> list[float]:
        """Force RMSE per axis over the noise floor's (nan where either is missing)."""
        return [a / b if b and b > 0 else math.nan for a, b in zip(getattr(self, which), self.noise)]


def _num(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def _axes(cell) -> list[float]:
    """``"0.0069 / 0.0051 / 0.0176"`` -> three numbers (nan where absent)."""
    parts = str(cell).split("/") if isinstance(cell, str) else []
    return [_num(p) for p in parts] if len(parts) == 3 else [math.nan] * 3


def parse_named(named) -> list[tuple[str, dict[str, float]]]:
    """``"linear_drag(kx=0.0125 N s/m, ky=0.0126 N s/m); cg_offset(rx=0.001 m)"`` (qr.stages.diagnose_sets.summary:
    each value followed by its unit, or bare) -> pairs of names and values."""
    if not isinstance(named, str) or named.strip() in ("", "none", "-"):
        return []
    out = []
    for name, params in re.findall(r"(\w+)\(([^)]*)\)", named):
        out.append((name, {k.strip(): _num((v.split() or [""])[0])
                           for k, v in (p.split("=", 1) for p in params.split(",") if "=" in p)}))
    return out


def _g(x: float, digits: int = 3) -> str:
    return "–" if not math.isfinite(x) else f"{x:.{digits}g}"


def _span(xs: list[float]) -> str:
    """The range of ratios over the axes: ``2.1–3.4×`` (one number where they agree to print)."""
    ok = [x for x in xs if math.isfinite(x)]
    if not ok:
        return "–"
    lo, hi = _g(min(ok), 2), _g(max(ok), 2)
    return f"{lo}×" if lo == hi else f"{lo}–{hi}×"


def _plain(name: str) -> str:
    return name.replace("_", " ")


def _list(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def set_sentence(r: SetResult) -> str:
    """What the diagnosis of one set found, from its numbers: the effects named and what they leave, or why
    nothing was named (up to noise, or a residual the catalog does not describe)."""
    nom, ext = r.over_noise("nominal"), r.over_noise("extended")
    fin = [x for x in nom if math.isfinite(x)]
    if not r.effects:
        if not fin:
            return "Nothing named; the table gives no noise floor to judge the nominal model's residual by."
        if max(fin) <= UP_TO_NOISE:
            return (f"Nothing named: the nominal model explains these flights up to noise (its held-out force "
                    f"residual is {_span(nom)} the noise floor).")
        return (f"Nothing named, yet the nominal model's held-out force residual is {_span(nom)} the noise floor: "
                "the effects of the catalog do not describe these flights (check the log's conventions, "
                "docs/spec/flight-log.md, and the vehicle file).")
    names = _list([_plain(n) for n, _ in r.effects])
    s = (f"{len(r.effects)} effect{'s' * (len(r.effects) > 1)} named ({names}): the held-out force residual goes "
         f"from {_span(nom)} to {_span(ext)} the noise floor")
    if all(math.isfinite(x) for x in r.replay):
        s += f", the open-loop replay drift from {_g(r.replay[0])} m to {_g(r.replay[1])} m"
    fin_ext = [x for x in ext if math.isfinite(x)]
    if fin_ext and max(fin_ext) > 2 * UP_TO_NOISE:
        s += f"; {_span(ext)} the noise floor is left: the named effects do not explain all of it"
    return s + "."


@dataclass(frozen=True)
class Rollout:
    """A set's held-out rollout ratios at the horizon (rows of results/tables/rollout_held_out.csv)."""

    set: str
    flights: int
    horizon: int  # steps
    seconds: float  # the horizon in s (nan where the table does not say)
    ratios: dict[str, dict[str, float]]  # model -> quantity -> MAE / rate_frozen's
    mae: dict[str, dict[str, float]]

    @property
    def ahead(self) -> str:
        return f"h = {self.horizon}" + (f", {self.seconds:.2g} s ahead" if math.isfinite(self.seconds) else "")

    @classmethod
    def of(cls, table: pd.DataFrame | None, name: str) -> "Rollout | None":
        if table is None or "set" not in table or not (table["set"] == name).any():
            return None
        rows = table[table["set"] == name]
        H = next((int(m[1]) for c in rows.columns if (m := re.fullmatch(r"[pvRw]@(\d+)", c))), 0)
        ratios = {str(r["model"]): {q: _num(r.get(f"{q} / rate_frozen")) for q in QUANTITY} for _, r in rows.iterrows()}
        mae = {str(r["model"]): {q: _num(r.get(f"{q}@{H}")) for q in QUANTITY} for _, r in rows.iterrows()}
        seconds = _num(rows["horizon (s)"].iloc[0]) if "horizon (s)" in rows else math.nan
        flights = int(rows["held-out flights"].iloc[0]) if "held-out flights" in rows else 0
        return cls(name, flights, H, seconds, ratios, mae)


def answer(sets: list[SetResult], rollouts: dict[str, Rollout]) -> str:
    """The page's first sentence: the first set's result and the position error of its rollout, from their
    numbers (each set's own sentence, :func:`set_sentence`, says the rest)."""
    if not sets:
        return "No flight set was diagnosed."
    r = sets[0]
    lead = f"On the {r.flights} {r.name} flights"
    if not r.effects:
        s = set_sentence(r)
        s = f"{lead}: {s[0].lower()}{s[1:]}"
    else:
        names = ", ".join(_plain(n) for n, _ in r.effects)
        s = (f"{lead} qr names {len(r.effects)} effect{'s' * (len(r.effects) > 1)} ({names}), which bring the "
             f"held-out force residual from {_span(r.over_noise('nominal'))} to {_span(r.over_noise('extended'))} "
             "the noise floor")
        if all(math.isfinite(x) for x in r.replay):
            s += f" and the open-loop replay drift from {_g(r.replay[0], 2)} m to {_g(r.replay[1], 2)} m"
        s += "."
    ro = rollouts.get(r.name)
    models = [m for m in (ro.ratios if ro else {}) if m not in ("hold", "rate_frozen")]
    if models:
        per = ", ".join(f"{m} {_g(ro.ratios[m]['p'], 2)}×" for m in models)
        s = s[:-1] + f"; {ro.ahead.split(', ')[-1]}, the position error is {per} the physics baseline's."
    return s


# ---- HTML ----

def _table(df: pd.DataFrame, caption: str) -> str:
    body = df.to_html(index=False, border=0, na_rep="–", float_format=lambda x: f"{x:.4g}", escape=True)
    return body.replace('<table class="dataframe">', f'<table><caption>{html.escape(caption)}</caption>', 1)


def effects_html(effects: list[tuple[str, dict[str, float]]]) -> str:
    """The named effects in a reader's words, each parameter with its unit (the catalog's)."""
    from ..effects import CATALOG, with_unit

    items = []
    for name, params in effects:
        eff = CATALOG.get(name)
        vals = ", ".join(f"{html.escape(k)} = {html.escape(with_unit(name, k, v, '.3g').replace('^2', '²'))}"
                         for k, v in params.items())
        meaning = f" — {html.escape(eff.meaning)}" if eff and eff.meaning else ""
        items.append(f"<li><b>{html.escape(_plain(name))}</b>{meaning}: {vals} <span class=\"muted\">"
                     f"(<code>{html.escape(name)}</code>)</span></li>")
    return f'<ul class="effects">{"".join(items)}</ul>' if items else ""


def gains_table(sets: list[SetResult]) -> pd.DataFrame:
    """Held-out gains, one row per set and quantity: narrow, so it never scrolls sideways."""
    fmt = lambda xs, d=3: " / ".join(_g(x, d) for x in xs)  # noqa: E731
    ratio = "÷ noise floor: nominal → extended"
    rows = []
    for r in sets:
        rows.append({"set": r.name, "held-out residual": "force x / y / z (N)", "nominal": fmt(r.nominal),
                     "extended": fmt(r.extended), "noise floor": fmt(r.noise),
                     ratio: f"{fmt(r.over_noise('nominal'), 2)} → {fmt(r.over_noise('extended'), 2)}"})
        rows.append({"set": r.name, "held-out residual": "torque x / y / z (N m)", "nominal": fmt(r.nominal_torque),
                     "extended": fmt(r.extended_torque), "noise floor": "–", ratio: "–"})
        rows.append({"set": r.name, "held-out residual": "open-loop replay drift (m)", "nominal": _g(r.replay[0]),
                     "extended": _g(r.replay[1]), "noise floor": "–", ratio: "–"})
    return pd.DataFrame(rows)


def rollout_table(table: pd.DataFrame) -> pd.DataFrame:
    """The rollout at the horizon, one row per set and model: MAE with its unit and its ratio."""
    units = {"p": "m", "v": "m/s", "R": "rad", "w": "rad/s"}
    rows = []
    for name in dict.fromkeys(table["set"]):
        ro = Rollout.of(table, name)
        for m in ro.ratios:
            rows.append({"set": name, "model": m, "at": ro.ahead, **{f"{QUANTITY[q]} ({units[q]})":
                         _cell(ro.mae[m][q], ro.ratios[m][q]) for q in QUANTITY}})
    return pd.DataFrame(rows)


def _cell(mae: float, ratio: float) -> str:
    return _g(mae) + (f" ({_g(ratio, 2)}×)" if math.isfinite(ratio) else "")


def _rollout_html(table: pd.DataFrame) -> str:
    df = rollout_table(table)
    where = "at the horizon"
    if df["at"].nunique() == 1:  # every set at the same horizon: said once, in the caption
        where, df = df["at"].iloc[0], df.drop(columns="at")
    return _table(df, f"Mean absolute error ({where}) per model and, in brackets, its ratio to the public "
                      "benchmark's physics baseline (rate_frozen); below 1 is better")


def held_out_line(gen: pd.DataFrame) -> str:
    """One sentence: what each set's splits held out (the rows of results/tables/generalization.csv)."""
    parts = []
    for name in dict.fromkeys(gen["set"]):
        rows = gen[(gen["set"] == name) & (gen["split"] != "repeat")]
        what = list(dict.fromkeys(rows["held_out"]))
        pooled = [w for w in what if "each in turn" in w]
        members = {x for p in pooled for x in p.split(", each in turn")[0].removeprefix("time scales ").split(", ")}
        what = pooled + [w for w in what if "each in turn" not in w and w.removeprefix("time scale ") not in members]
        if what:
            parts.append(f"{name}: {'; '.join(what)}")
    s = ("Held out, never trained on — " + "; ".join(f"{p}" for p in parts) + ". ") if parts else ""
    return s + ("The repeat split (every third flight) is set beside them: where a set flies each trajectory "
                "several times, its held-out flights repeat training trajectories, so it measures interpolation.")


def _generalization_html(gen: pd.DataFrame) -> str:
    df = gen.copy()
    empty = df["coverage90"].isna().all()
    if empty:
        df = df.drop(columns="coverage90")
    df = df.rename(columns={"held_out": "held out", "p": "position", "v": "velocity", "R": "attitude",
                            "w": "body rate"})
    cap = ("Rollout on flights the models were not trained on: each model's error at h = 50 as a multiple of the "
           "physics baseline's (rate_frozen) on the same held-out windows; below 1 is better"
           + ("; no uncertainty bands yet (coverage90 empty)" if empty else ""))
    return f"<p>{html.escape(held_out_line(gen))}</p>" + _table(df, cap)


def _figure(path: Path, caption: str) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode()
    return (f'<figure><figcaption>{html.escape(caption)}</figcaption>'
            f'<img alt="{html.escape(caption)}" src="data:image/png;base64,{data}"></figure>')


def replay_table(table: pd.DataFrame) -> pd.DataFrame:
    """The closed-loop replay, one row per set and model: RMSE with units, when it parts, its ratio to nominal."""
    rows = []
    for _, r in table.iterrows():
        parts = r.get("parts at (s)")
        rows.append({"set": r["set"], "model": r["model"], "flights": int(r["flights"]),
                     "position RMSE (m)": _g(r["position RMSE (m)"]) + _times(r.get("position / nominal")),
                     "attitude RMSE (°)": _g(r["attitude RMSE (deg)"]) + _times(r.get("attitude / nominal")),
                     "rotor speeds RMSE (%)": _g(r["rotor speeds RMSE (%)"]),
                     "parts from the log after (s)": "never" if parts is None or not math.isfinite(_num(parts))
                     else _g(_num(parts))})
    return pd.DataFrame(rows)


def _times(ratio) -> str:
    x = _num(ratio) if ratio is not None else math.nan
    return f" ({_g(x, 2)}×)" if math.isfinite(x) else ""


def overview_html(diagnosis: pd.DataFrame, rollout: pd.DataFrame | None, thesis: dict[str, pd.DataFrame],
                  figures: list[tuple[Path, str]], title: str = "qr: what the quadrotor model gets wrong",
                  fragment: bool = False, generalization: pd.DataFrame | None = None,
                  replay: pd.DataFrame | None = None) -> str:
    """The page; ``fragment``: its body in a ``div.qr-overview`` with the style scoped to it (the
    landing page of Snakemake's report, ``workflow/report/workflow.rst``)."""
    sets = [SetResult.from_row(row) for _, row in diagnosis.iterrows()]
    rollouts = {r.name: ro for r in sets if (ro := Rollout.of(rollout, r.name)) is not None}
    parts = [f"<h1>{html.escape(title)}</h1>", f'<p class="answer">{html.escape(answer(sets, rollouts))}</p>',
             '<p class="muted">Generated by the workflow from results/tables/ (diagnosis_summary, '
             "generalization, rollout_held_out, the learning tables); the other pages of this report hold "
             "every output with its caption.</p>", "<h2>What was diagnosed, and what the nominal model gets wrong</h2>"]
    for r in sets:
        parts.append(f"<h3>{html.escape(r.name)}: {r.flights} flights, {r.samples} samples</h3>")
        parts.append(f"<p>{html.escape(set_sentence(r))}</p>")
        parts.append(effects_html(r.effects))
    parts.append(_table(gains_table(sets), "Held-out gains: the residual of the nominal and the extended model "
                                           "(RMSE per axis) beside the noise floor, and the open-loop replay drift; "
                                           "the extended model is the nominal one plus the named effects"))
    if generalization is not None and len(generalization):
        parts.append("<h2>Generalisation: rollout on trajectories not trained on</h2>")
        parts.append(_generalization_html(generalization))
    if rollout is not None and len(rollout):
        parts.append("<h2>Multi-step rollout on held-out flights (every third flight: same trajectories)</h2>")
        parts.append(_rollout_html(rollout))
    if replay is not None and len(replay):
        parts.append("<h2>Closed-loop replay under the vehicle's own controller</h2>")
        parts.append(_table(replay_table(replay), "Each model flown in closed loop under the controller the flights "
                            "flew (qr replay) along their rebuilt setpoints, against the held-out logs: RMSE over the "
                            "flights and, in brackets, over the nominal model's (the first row of each set); the "
                            "held-out flights repeat the training trajectories (interpolation)"))
    if thesis:
        parts.append("<h2>Residual learning: the thesis tables</h2>")
        for name, df in thesis.items():
            parts.append(_table(df, name))
    if figures:
        parts.append("<h2>Figures</h2>")
        parts.extend(_figure(p, c) for p, c in figures)
    if fragment:
        return f'<div class="qr-overview"><style>{_style(".qr-overview")}\n{LANDING}</style>{"".join(parts)}</div>'
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{STYLE}</style></head><body>{''.join(parts)}</body></html>")


def _title(csv: Path) -> str:
    """The table's own title: the first line of its Markdown twin (qr.report.tables.write_table)."""
    md = csv.with_suffix(".md")
    first = md.read_text().splitlines()[0] if md.exists() else ""
    return first.lstrip("#").strip() or csv.stem


def fragment_path(out) -> Path:
    """Where the landing-page fragment of the overview ``out`` goes: ``overview.fragment.html``."""
    out = Path(out)
    return out.with_name(out.name.removesuffix(".html") + ".fragment.html")


def write_overview(out, diagnosis_csv, rollout_csv=None, thesis_csvs: dict | None = None,
                   figures: list[tuple[str, str]] = (), fragment_out=None, generalization_csv=None,
                   replay_csv=None) -> None:
    """Write the page ``out`` and its landing-page fragment (``fragment_out``, default :func:`fragment_path`).
    ``figures``: (png, caption) pairs; a missing png (a reduced run) is left out."""
    thesis = {_title(Path(v)): pd.read_csv(v) for v in (thesis_csvs or {}).values() if Path(v).exists()}
    rollout = pd.read_csv(rollout_csv) if rollout_csv and Path(rollout_csv).exists() else None
    figs = [(Path(p), c) for p, c in figures if Path(p).exists()]
    diagnosis = pd.read_csv(diagnosis_csv)
    gen = pd.read_csv(generalization_csv) if generalization_csv and Path(generalization_csv).exists() else None
    replay = pd.read_csv(replay_csv) if replay_csv and Path(replay_csv).exists() else None
    for path, fragment in ((out, False), (fragment_out or fragment_path(out), True)):
        text = overview_html(diagnosis, rollout, thesis, figs, fragment=fragment, generalization=gen, replay=replay)
        with atomic_path(path, suffix=".html") as tmp:
            Path(tmp).write_text(text)
