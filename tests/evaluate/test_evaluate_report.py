"""``qr evaluate``'s report.md: its sentence is built from evaluation.json's numbers (read back here and
checked against ratios computed from the MAE lists), its tables are narrow, its figure runs in seconds
and names the models as the tables do."""

import re

import numpy as np
import pytest

from qr.evaluate import report as rep

Q = ("p", "v", "R", "w")


def _doc(ends: dict, H=50, dt=0.01, labels=None, flights=("a.csv",)):
    """An evaluation document whose MAE grows linearly to ``ends[model][q]`` at h = H."""
    def block(end):
        return {q: {"mae": [None if end[q] is None else end[q] * h / H for h in range(1, H + 1)],
                    "simerr": None if end[q] is None else end[q] * (H + 1) / 2, "windows": 100} for q in Q}

    models = {m: block(e) for m, e in ends.items()}
    doc = {"schema": "qr.evaluation/1", "flights": list(flights), "vehicles": [m for m in ends if m not in
                                                                                rep.REFERENCES],
           "dt": dt, "dt_range": [dt, dt], "horizon": H, "models": models,
           "per_flight": {f: {"models": models} for f in flights}}
    if labels:
        doc["labels"] = labels
    return doc


ENDS = {"hold": dict(p=1.0, v=2.0, R=1.0, w=3.0), "rate_frozen": dict(p=0.1, v=0.5, R=0.2, w=0.8),
        "cf.yaml": dict(p=0.42, v=2.0, R=0.72, w=10.4), "extended_vehicle.yaml": dict(p=0.12, v=0.575, R=0.238, w=2.48),
        "hybrid.yaml": dict(p=0.06, v=0.325, R=0.154, w=0.832)}


def _claims(sentence: str) -> dict[str, list[float]]:
    """'NAME a / b / c / d' groups of the sentence: model label -> its four ratios."""
    part = sentence.split(": ", 1)[1].split("; lowest")[0].split("; better")[0].split("; no model")[0]
    out = {}
    for item in part.split("; "):
        name, nums = re.match(r"(.+?) ([-–\d.e/ ]+)$", item).groups()
        out[name] = [float(x) if x.strip() != "–" else None for x in nums.split(" / ")]
    return out


def test_the_sentence_states_each_models_ratios_to_the_baseline_and_they_are_the_numbers():
    labels = {"cf.yaml": "nominal", "extended_vehicle.yaml": "extended", "hybrid.yaml": "hybrid"}
    doc = _doc(ENDS, labels=labels)
    s = rep.headline(doc)
    assert s.startswith("At h = 50 steps (0.50 s ahead)") and "`rate_frozen`" in s
    claims = _claims(s)
    assert list(claims) == ["nominal", "extended", "hybrid"]
    for key, label in labels.items():
        want = [ENDS[key][q] / ENDS["rate_frozen"][q] for q in Q]  # by hand: end over the baseline's end
        np.testing.assert_allclose(claims[label], want, rtol=5e-3)  # printed to 3 digits
    # the hybrid is lowest on everything; better than the baseline where its ratio < 1
    assert "lowest: hybrid on position, velocity, attitude and body rate" in s
    assert s.endswith("; better than the baseline: hybrid on position, velocity and attitude.")  # 0.6, 0.65, 0.77


def test_the_lowest_and_better_clauses_follow_the_numbers():
    ends = {**ENDS, "hybrid.yaml": dict(p=0.06, v=0.325, R=0.154, w=12.0)}  # the hybrid's body rate worst
    doc = _doc({k: ends[k] for k in ("hold", "rate_frozen", "extended_vehicle.yaml", "hybrid.yaml")})
    s = rep.headline(doc)
    assert "lowest: hybrid.yaml on position, velocity and attitude, extended_vehicle.yaml on body rate" in s
    worse = _doc({"hold": ENDS["hold"], "rate_frozen": ENDS["rate_frozen"], "cf.yaml": ENDS["cf.yaml"]})
    s = rep.headline(worse)
    assert "lowest" not in s and s.endswith("; no model beats the baseline.")
    assert _claims(s)["cf.yaml"] == pytest.approx([4.2, 4.0, 3.6, 13.0], rel=5e-3)


def test_a_quantity_without_windows_is_a_dash_not_a_number():
    ends = {**ENDS, "cf.yaml": dict(p=0.42, v=2.0, R=None, w=10.4)}
    s = rep.headline(_doc({k: ends[k] for k in ("hold", "rate_frozen", "cf.yaml")}))
    assert _claims(s)["cf.yaml"][2] is None and "cf.yaml 4.2 / 4 / – / 13" in s


def test_the_report_opens_with_the_sentence_and_its_tables_are_narrow():
    doc = _doc(ENDS, flights=("a.csv", "b.csv"))
    text = rep.report(doc, "figures/rollout_mae.png")
    lines = text.splitlines()
    assert lines[0].startswith("# Rollout evaluation") and lines[2] == rep.headline(doc)
    widths = [line.count("|") - 1 for line in lines if line.startswith("|")]
    assert widths and max(widths) <= 5  # model + four quantities (the old tables had 16 columns)
    # the table at the horizon: MAE with its unit and the ratio, the same numbers as the sentence
    row = next(line for line in lines if line.startswith("| hybrid.yaml |"))
    assert "0.06 m (0.6×)" in row and "0.832 rad/s (1.04×)" in row
    assert f"*{rep.FIGURE_CAPTION}*" in text and "## Per flight" in text


def test_the_figure_runs_in_seconds_and_names_the_models_as_the_tables(tmp_path, monkeypatch):
    from qr.report import figures

    drawn = {}
    monkeypatch.setattr(figures, "save", lambda fig, path, tight=True: drawn.setdefault("fig", fig))
    labels = {"cf.yaml": "nominal", "extended_vehicle.yaml": "extended", "hybrid.yaml": "hybrid"}
    rep.mae_figure(_doc(ENDS, H=50, dt=0.004, labels=labels), tmp_path / "f.png")
    ax = drawn["fig"].axes[0]
    assert ax.get_xlabel() == "time ahead (s)"
    x = ax.lines[0].get_xdata()
    assert x[0] == pytest.approx(0.004) and x[-1] == pytest.approx(0.2)  # h · dt, h = 1 .. 50
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend == ["hold", "rate_frozen", "nominal", "extended", "hybrid"]
