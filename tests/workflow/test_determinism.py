"""Same seed, same results: two full runs of the reduced workflow give identical tables.

The two runs (tests/workflow_runs.py) are an uninterrupted `snakemake --cores 2 --configfile
conf/workflow_ci.yaml` and the run of tests/workflow/test_faults.py, which was interrupted with Ctrl-C and
with SIGKILL and resumed: every job of it ran from scratch too, some of them twice.  Every CSV
table under results/ is compared exactly, wall-clock columns (training time) aside.
"""

import pandas as pd
import pytest

import workflow_runs as wr

# the whole-workflow runs are shared (memoised) between these modules: keep them on one xdist worker
pytestmark = pytest.mark.xdist_group("reduced_workflow")


@pytest.fixture(scope="session")
def clean(tmp_path_factory):
    return wr.clean_run(tmp_path_factory)


@pytest.fixture(scope="session")
def faulted(tmp_path_factory):
    return wr.faulted_run(tmp_path_factory)


def test_two_full_runs_give_identical_tables(clean, faulted):
    a, b = wr.tables(clean), wr.tables(faulted["results"])
    assert faulted["resume_rc"] == 0, faulted["resume_log"]
    assert sorted(a) == sorted(b)
    # every stage's tables are there (a stage added to `rule all` later is compared too)
    for expected in ("ingest/summary.csv", "filter/summary.csv", "tables/table_4_2.csv", "tables/table_4_3.csv",
                     "tables/table_3_1.csv", "tables/gpr_kernels.csv", "simulation/tracking.csv",
                     "simulation/stability.csv", "tables/rollout_held_out.csv", "tables/generalization.csv"):
        assert expected in a
    for name in a:
        assert len(a[name]) > 0, name
        pd.testing.assert_frame_equal(a[name], b[name], check_exact=True, obj=name)


def test_two_full_runs_give_identical_state_tables(clean, faulted):
    """The canonical flights and the filters' state tables too (Parquet, compared value by value)."""
    for sub in ("ingest", "filter"):
        files = sorted(p.relative_to(clean) for p in (clean / sub).rglob("*.parquet"))
        assert files
        for rel in files:
            pd.testing.assert_frame_equal(pd.read_parquet(clean / rel), pd.read_parquet(faulted["results"] / rel),
                                          check_exact=True, obj=str(rel))


def test_the_report_opens_on_the_overview(clean):
    """`snakemake --report` on a finished run: its landing page (workflow/report/workflow.rst) holds the
    overview — the named effects and the tables, generated, with the style scoped to it."""
    import html
    import re

    path = clean.parent
    wr.snakemake(path, "--report", "report.html", "--configfile", wr.CI_CONFIG, log="report.log", QR_TRACKING="off")
    text = (path / "report.html").read_text()
    fragment = (clean / "overview.fragment.html").read_text()
    named = pd.read_csv(clean / "tables" / "diagnosis_summary.csv")["named"].dropna()
    first = str(named.iloc[0]).split(";")[0].split("(")[0].strip()
    assert first and first != "none"
    first = first.replace("_", " ")  # the overview names effects in words
    # the report embeds its landing page as a JSON string: compare on unescaped text
    landing = html.unescape(text.encode().decode("unicode_escape", errors="ignore"))
    assert "qr-overview" in landing and first in landing
    assert first in fragment and "<body" not in fragment
    style = re.search(r"<style>(.*?)</style>", fragment, re.S).group(1)
    assert all(line.startswith(".qr-overview") or ":has(.qr-overview)" in line
               for line in style.strip().splitlines())


def test_the_held_out_rollout_names_the_vehicle_files_it_compared(clean):
    """evaluation.json lists each compared vehicle by a file that is still there after the run (the models
    the training diagnosis gives are kept beside it), with the label the tables use."""
    import json
    from pathlib import Path

    docs = sorted((clean / "evaluation").glob("*/held_out/evaluation.json"))
    assert docs
    # (a hybrid where the training diagnosis learned a remainder: the brushless set's; the payload set's one
    # training flight may be refused as not described, and then carries none)
    hybrid = json.loads((clean / "evaluation" / "brushless" / "held_out" / "evaluation.json").read_text())
    assert "hybrid" in hybrid["labels"].values(), hybrid["labels"]
    for p in docs:
        doc = json.loads(p.read_text())
        assert set(doc["labels"].values()) >= {"nominal", "extended"}, doc["labels"]
        for v in doc["vehicles"]:
            assert (clean.parent / v).is_file() or Path(v).is_file(), v  # not in a temporary folder


def test_the_generalization_table_holds_the_repeat_split_and_a_fold_that_trained_what_it_scored(clean):
    """The reduced run's one fold (brushless: trained on time scale 1.0, scored on 0.9) beside the repeat split:
    the table's exact columns, the fold's residual row, its flights on one side each, its envelope check."""
    import json

    g = pd.read_csv(clean / "tables" / "generalization.csv")
    assert list(g.columns) == ["set", "split", "held_out", "model", "p", "v", "R", "w", "coverage90"]
    assert set(g["split"]) == {"repeat", "speed"}
    # the residuals this run trains carry a band (learn.members=2 in the reduced run: the brushless one and the
    # payload's fine-tune; the carried-over one is scored as trained, without members), the physical models none
    # (the reduced run's training diagnosis is not refined: no parameter covariance)
    banded = g["model"].isin(["hybrid (rollout-trained)", "hybrid (rollout-trained, fine-tuned)"])
    assert g.loc[banded, "coverage90"].between(0, 1).all() and g.loc[~banded, "coverage90"].isna().all()
    speed = g[g["split"] == "speed"]
    assert "hybrid (rollout-trained)" in set(speed["model"]) and (speed[["p", "v", "R", "w"]] > 0).all().all()
    fold = clean / "generalization" / "brushless" / "speed-fastest"
    split = json.loads((fold / "fold.json").read_text())["split"]
    assert [p.split("/")[-1] for p in split["train"]] == ["eckart00.parquet"]
    assert [p.split("/")[-1] for p in split["test"]] == ["eckart06.parquet"]
    doc = json.loads((fold / "held_out" / "evaluation.json").read_text())
    assert doc["envelope"]["trained_on"] == split["train"] and doc["flights"] == split["test"]
    training = json.loads((fold / "residual" / "training.json").read_text())
    assert not set(training["flights"]["training"] + training["flights"]["validation"]) & set(split["test"])
    assert training["config"]["evaluate"]["split"]["kind"] == "speed"  # the split it was trained under


def test_every_residual_trained_on_one_torch_thread(clean):
    """The rules' trainings read their estimates from the filter stage's files, so numba's OpenMP pool was
    first launched inside the training, which set torch's thread count back to numba's: 2 threads, 5x the
    wall on loaded cores (qr.parallel.torch_one_thread).  Each training.json records the threads seen."""
    import json

    files = sorted(clean.rglob("training.json"))
    assert any("learn" in f.parts for f in files) and any("generalization" in f.parts for f in files), files
    for f in files:
        assert json.loads(f.read_text())["software"]["threads"] == 1, f
