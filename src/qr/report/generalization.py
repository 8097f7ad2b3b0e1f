"""``results/tables/generalization.csv``: how the models do on flights they were not trained on, per set and
split (docs/evaluate.md, "Held-out splits"; docs/workflow.md, "Generalisation").

Columns exactly ``set, split, held_out, model, p, v, R, w, coverage90``: each model's MAE at h = H (50) over
``rate_frozen``'s on the same windows (position, velocity, attitude, body rate; below 1 is better), and
the share of held-out samples at h = H inside the model's 90 % band (empty where the evaluation carries
no bands: ``evaluation.json``'s ``bands.<model>.coverage90``, written once bands exist).  ``split`` is
``repeat`` (every third flight: the same trajectories, interpolation), ``trajectory`` or ``speed``; a
group of folds (one per time scale or trajectory type) adds a pooled row, each model's MAE summed over
the folds' windows.  The Markdown twin adds, per fold, the share of held-out windows outside the
training envelope (:mod:`qr.envelope`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from ..rollout import QUANTITIES, REFERENCES, at

COLUMNS = ["set", "split", "held_out", "model", *QUANTITIES, "coverage90"]
BASELINE = "rate_frozen"
# the label the held-out protocol gives the extended model plus its learned linear torque remainder
RENAME = {"hybrid": "hybrid (linear remainder)"}


@dataclass(frozen=True)
class Scored:
    """One evaluation of a fold: its documents (a held-out rollout and, where trained, the residual's)."""

    set: str
    split: str
    held_out: str
    docs: tuple  # evaluation.json documents, models added in order (each label once)
    group: str | None = None  # folds of one group are pooled
    envelope: float | None = None  # share of held-out windows outside the training envelope


def _coverage(doc: dict, model: str):
    c = ((doc.get("bands") or {}).get(model) or {}).get("coverage90")
    return math.nan if c is None else float(c)


def _label(doc: dict, key: str) -> str:
    lab = (doc.get("labels") or {}).get(key, key)
    return RENAME.get(lab, lab)


def _models(docs) -> list[tuple[str, dict, str]]:
    """(label, doc, key) of each scored model, each label once, in order (the references left out)."""
    seen, out = set(), []
    for doc in docs:
        for k in doc["models"]:
            lab = _label(doc, k)
            if k in REFERENCES or lab in seen:
                continue
            seen.add(lab)
            out.append((lab, doc, k))
    return out


def rows_of(s: Scored) -> list[dict]:
    rows = []
    for lab, doc, k in _models(s.docs):
        H, m = doc["horizon"], doc["models"]
        row = {"set": s.set, "split": s.split, "held_out": s.held_out, "model": lab}
        for q in QUANTITIES:
            x, b = at(m[k], H, q), at(m[BASELINE], H, q)
            row[q] = x / b if x is not None and b else math.nan
        row["coverage90"] = _coverage(doc, k)
        rows.append(row)
    return rows


def pooled_rows(group: list[Scored], held_out: str) -> list[dict]:
    """Each model's MAE at H pooled over the folds it was scored in (each fold's MAE times its window count),
    over ``rate_frozen``'s pooled over the same folds' windows."""
    sums: dict[str, dict[str, list[float]]] = {}
    for s in group:
        for lab, doc, k in _models(s.docs):
            H = doc["horizon"]
            acc = sums.setdefault(lab, {q: [0.0, 0, 0.0, 0] for q in QUANTITIES})
            for q in QUANTITIES:
                for j, blk in ((0, doc["models"][k]), (2, doc["models"][BASELINE])):
                    x, n = at(blk, H, q), blk[q].get("windows", 0)
                    if x is not None and n:
                        acc[q][j] += x * n
                        acc[q][j + 1] += n
    rows = []
    for lab, acc in sums.items():
        row = {"set": group[0].set, "split": group[0].split, "held_out": held_out, "model": lab}
        for q in QUANTITIES:
            x, nx, b, nb = acc[q]
            row[q] = (x / nx) / (b / nb) if nx and nb and b else math.nan
        row["coverage90"] = _pooled_coverage(group, lab)
        rows.append(row)
    return rows


def _pooled_coverage(group: list[Scored], lab: str) -> float:
    """The 90 % band's coverage of ``lab`` over the folds' samples (per quantity weighted by its samples, then
    the mean over the quantities, as each evaluation's ``coverage90``); NaN unless every fold has the band."""
    hit: dict[str, list[float]] = {}
    for s in group:
        found = [(doc, k) for l2, doc, k in _models(s.docs) if l2 == lab]
        band = ((found[0][0].get("bands") or {}).get(found[0][1]) or {}) if found else {}
        if not band.get("by_quantity"):
            return math.nan
        for q, b in band["by_quantity"].items():
            if b.get("coverage90") is not None and b.get("samples"):
                acc = hit.setdefault(q, [0.0, 0])
                acc[0] += b["coverage90"] * b["samples"]
                acc[1] += b["samples"]
    shares = [a / n for a, n in hit.values() if n]
    return float(sum(shares) / len(shares)) if shares else math.nan


def _envelope_share(docs) -> float | None:
    env = (docs[0].get("envelope") or {}) if docs else {}
    return env.get("share_outside")


def read_scored(set_name: str, split: str, held_out: str | None, dirs, group: str | None = None) -> Scored:
    """Evaluations (folders holding ``evaluation.json``) of one split; ``held_out``: in words (default: the
    first evaluation's ``split.held_out``)."""
    docs = tuple(json.loads((Path(d) / "evaluation.json").read_text()) for d in dirs)
    if held_out is None:
        held_out = (docs[0].get("split") or {}).get("held_out", "every third flight")
    return Scored(set_name, split, held_out, docs, group, _envelope_share(docs))


def read_fold(set_name: str, fold_dir) -> Scored:
    """A fold of rule ``generalization_fold`` (its ``fold.json`` and evaluations)."""
    fold_dir = Path(fold_dir)
    f = json.loads((fold_dir / "fold.json").read_text())
    return read_scored(set_name, f["fold"]["kind"], f["split"]["held_out"],
                       [fold_dir / e for e in f["evaluations"]], f["fold"].get("group"))


def group_text(group: list[Scored]) -> str:
    """What a pooled group of folds held out: ``time scales 1, 0.9, … each in turn (6 folds, pooled)``."""
    what = [s.held_out for s in group]
    if all(w.startswith("time scale ") for w in what):
        what = ["time scales " + ", ".join(w.removeprefix("time scale ") for w in what)]
    return f"{', '.join(what)}, each in turn ({len(group)} folds, pooled)"


def table(scored: list[Scored]) -> pd.DataFrame:
    """The rows of every evaluation, a pooled row set after each group's last fold."""
    rows, done = [], set()
    for k, s in enumerate(scored):
        rows += rows_of(s)
        g = s.group
        if g and g not in done and not any(t.group == g and t.set == s.set for t in scored[k + 1:]):
            members = [t for t in scored if t.group == g and t.set == s.set]
            if len(members) > 1:
                rows += pooled_rows(members, group_text(members))
            done.add(g)
    return pd.DataFrame(rows, columns=COLUMNS)


def notes(scored: list[Scored], df: pd.DataFrame) -> list[str]:
    """Lines under the Markdown table: what the splits mean, the envelope per fold, the empty coverage."""
    lines = ["", "Ratio of each model's mean absolute error at h = 50 to `rate_frozen`'s on the same held-out "
             "windows (p / v / R / w: position, velocity, attitude, body rate; below 1 is better). `repeat`: "
             "every third flight held out; where a set flies each trajectory several times the held-out flights "
             "repeat training trajectories, so it measures interpolation. `trajectory` and `speed`: the scored "
             "flights fly what no training flight flew (another trajectory type or time scale; faster flights).", ""]
    if df["coverage90"].isna().all():
        lines.append("coverage90 is empty: no evaluation carries uncertainty bands yet.")
        lines.append("")
    env = [s for s in scored if s.envelope is not None]
    if env:
        lines.append("Held-out windows outside the training flights' envelope (speed, tilt, rotor speeds, body "
                     "rates beyond anything the training flights did; `qr evaluate`'s report lists them):")
        lines.append("")
        lines += [f"- {s.set}, {s.split}, {s.held_out}: {100 * s.envelope:.3g} %" for s in env]
    return lines


def write(scored: list[Scored], csv_path, skipped=()) -> pd.DataFrame:
    """The CSV and its Markdown twin (``skipped``: folds not run, ``"set/fold: why"``, listed under it)."""
    from ..atomic import write_text
    from .tables import write_table

    df = table(scored)
    write_table(df, csv_path, title="Generalisation: rollout on held-out flights per split (ratio to rate_frozen at "
                                    "h = 50)")
    md = Path(csv_path).with_suffix(".md")
    extra = (["", "Folds not run (the run's flights cannot make them):", ""] + [f"- {x}" for x in skipped]
             if skipped else [])
    write_text(md, md.read_text() + "\n".join(notes(scored, df) + extra) + "\n")
    return df
