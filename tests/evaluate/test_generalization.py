"""results/tables/generalization.csv (qr.report.generalization) from evaluation documents with numbers set by
hand: each ratio is the model's MAE at h = H over rate_frozen's, a group of folds pools the MAE over the
folds' windows, the coverage is read where bands exist and left empty otherwise."""

import json
import math

import pandas as pd
import pytest

from qr.report.generalization import COLUMNS, Scored, read_fold, table, write


def _block(x, n):
    return {q: {"mae": [None, x], "simerr": x, "windows": n} for q in ("p", "v", "R", "w")}


def _doc(models: dict, labels: dict, n=100, held="time scale 0.5", bands=None, share=None):
    doc = {"horizon": 2, "dt": 0.01, "labels": labels, "split": {"held_out": held},
           "models": {"hold": _block(9.0, n), **{k: _block(x, n) for k, x in models.items()}}}
    if bands:
        doc["bands"] = bands
    if share is not None:
        doc["envelope"] = {"share_outside": share}
    return doc


def test_ratios_labels_pooled_rows_and_coverage():
    a = _doc({"rate_frozen": 2.0, "n.yaml": 4.0, "h.yaml": 1.0}, {"n.yaml": "nominal", "h.yaml": "hybrid"}, n=100,
             bands={"h.yaml": {"coverage90": 0.85}}, share=0.25)
    b = _doc({"rate_frozen": 1.0, "n.yaml": 3.0, "h.yaml": 0.5}, {"n.yaml": "nominal", "h.yaml": "hybrid"}, n=300,
             held="time scale 0.6")
    learned = _doc({"rate_frozen": 2.0, "n.yaml": 4.0, "r.yaml": 1.5},
                   {"n.yaml": "nominal", "r.yaml": "hybrid (rollout-trained)"})
    scored = [Scored("s", "trajectory", "time scale 0.5", (a, learned), "g", 0.25),
              Scored("s", "trajectory", "time scale 0.6", (b,), "g")]
    df = table(scored)
    assert list(df.columns) == COLUMNS == ["set", "split", "held_out", "model", "p", "v", "R", "w", "coverage90"]
    first = df[df["held_out"] == "time scale 0.5"].set_index("model")
    # the linear-remainder hybrid renamed; the learned evaluation's nominal not repeated
    assert list(first.index) == ["nominal", "hybrid (linear remainder)", "hybrid (rollout-trained)"]
    assert first.loc["nominal", "p"] == 2.0 and first.loc["hybrid (rollout-trained)", "w"] == 0.75
    assert first.loc["hybrid (linear remainder)", "coverage90"] == 0.85
    assert math.isnan(first.loc["nominal", "coverage90"])
    pooled = df[df["held_out"].str.contains("each in turn")].set_index("model")
    assert pooled.index[0] == "nominal" and "time scales 0.5, 0.6, each in turn (2 folds, pooled)" in df["held_out"].values
    # nominal: (4·100 + 3·300) / 400 over rate_frozen (2·100 + 1·300) / 400
    assert pooled.loc["nominal", "p"] == pytest.approx((4 * 100 + 3 * 300) / (2 * 100 + 1 * 300))
    # a model only one fold has: that fold's windows alone, the baseline's on the same windows
    assert pooled.loc["hybrid (rollout-trained)", "p"] == pytest.approx(1.5 / 2.0)


def test_the_workflows_fold_folder_is_read_and_the_markdown_says_what_the_splits_mean(tmp_path):
    fold = tmp_path / "fold"
    for sub, doc in (("held_out", _doc({"rate_frozen": 2.0, "x.yaml": 1.0}, {"x.yaml": "physical (refined)"},
                                      held="sideways", share=0.4)),):
        (fold / sub).mkdir(parents=True)
        (fold / sub / "evaluation.json").write_text(json.dumps(doc))
    (fold / "fold.json").write_text(json.dumps({"fold": {"kind": "trajectory", "group": None},
                                                "split": {"held_out": "sideways"}, "evaluations": ["held_out"]}))
    s = read_fold("payload", fold)
    assert (s.split, s.held_out, s.envelope) == ("trajectory", "sideways", 0.4)
    df = write([s], tmp_path / "generalization.csv")
    back = pd.read_csv(tmp_path / "generalization.csv")
    assert list(back.columns) == COLUMNS and back.loc[0, "model"] == "physical (refined)" and back.loc[0, "p"] == 0.5
    assert back["coverage90"].isna().all() and len(df) == 1
    md = (tmp_path / "generalization.md").read_text()
    assert "measures interpolation" in md and "coverage90 is empty" in md
    assert "- payload, trajectory, sideways: 40 %" in md
