"""The Snakemake workflow: lint-clean, its rule graph as docs/workflow.md draws it, ingest on real data."""

import re
import subprocess

import pandas as pd

from conftest import ROOT

SNAKEMAKE = str(ROOT / ".venv" / "bin" / "snakemake")


def _rulegraph_edges():
    dot = subprocess.run([SNAKEMAKE, "--rulegraph", "--quiet", "all"], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout
    labels = dict(re.findall(r'(\d+)\[label = "([^"]+)"', dot))
    # the ingest and filter jobs are one rule per batch of a set's flights (ingest_<set>_<k>): drawn as one
    batch = {i: re.sub(r"^(ingest|filter)_\w+_\d+$", r"\1", name) for i, name in labels.items()}
    assert {n for n in batch.values() if n in ("ingest", "filter")} == {"ingest", "filter"}, labels
    return {(batch[a], batch[b]) for a, b in re.findall(r"(\d+) -> (\d+)", dot)}


def test_readme_rule_graph_is_true():
    readme = (ROOT / "docs" / "workflow.md").read_text()
    block = readme.split("```\nrule graph\n", 1)[1].split("```", 1)[0]
    drawn = {tuple(line.split(" -> ")) for line in (x.strip() for x in block.splitlines()) if "->" in line}
    assert drawn == _rulegraph_edges()


def test_lint_clean():
    out = subprocess.run([SNAKEMAKE, "--lint"], cwd=ROOT, capture_output=True, text=True)
    assert "Lints for" not in out.stdout + out.stderr, out.stdout


def test_ingest_and_summary_on_a_subset(tmp_path):
    """Two flights per set through `ingest` and `summary` in a scratch working directory."""
    data = (ROOT / "conf" / "data" / "imrclab_crazyflie.yaml").read_text()
    import yaml

    d = yaml.safe_load(data)
    d["root"] = str((ROOT / d["root"]).resolve())
    for s in d["sets"].values():
        s["flights"] = s["flights"][:2]
    (tmp_path / "data.yaml").write_text(yaml.safe_dump(d))
    for name in ("conf", "workflow", "Snakefile"):
        (tmp_path / name).symlink_to(ROOT / name)
    subprocess.run([SNAKEMAKE, "--cores", "2", "--quiet", "--config", f"data={tmp_path / 'data.yaml'}",
                    "--", "results/ingest/summary.csv"], cwd=tmp_path, check=True, capture_output=True,
                   env={**__import__("os").environ, "QR_RESULTS": str(tmp_path / "results")})
    table = pd.read_csv(tmp_path / "results" / "ingest" / "summary.csv")
    assert sorted(table["set"]) == ["brushed"] * 2 + ["brushless"] * 2 + ["payload"] * 2
    assert (table["rows"] > 300).all()
    # the brushed logs' motion capture arrives at ~90 Hz (median step 11 ms), the others' at 100 Hz
    assert table["rate_hz"].where(table["set"] != "brushed").dropna().between(95, 105).all()
    assert table.loc[table["set"] == "brushed", "rate_hz"].between(85, 95).all()
    assert (tmp_path / "results" / "ingest" / "summary_by_set.md").exists()
    assert (tmp_path / "results" / "figures" / "ingest_residual_z.png").stat().st_size > 1000
    assert (tmp_path / "results" / "benchmarks" / "ingest" / "summary.tsv").exists()


def test_a_job_that_fails_on_bad_input_says_why_in_its_log_and_in_snakemakes_output(tmp_path):
    """A user's data set with a broken flight: the ingest job ends with qr's one line (file, problem, fix) in its
    log file and in what Snakemake prints.  The scripts' own stderr redirection lost it before: the log was
    closed when Python printed the error ("lost sys.stderr"), so the user saw neither."""
    import os

    import yaml

    (tmp_path / "data" / "csv").mkdir(parents=True)
    (tmp_path / "data" / "csv" / "f0.csv").write_text("t,x\n0.0,1.0\n0.01,1.0\n")  # no attitude, no rotors
    spec = {"name": "broken", "root": str(tmp_path / "data"), "format": "auto",
            "sets": {"bad": {"dir": "csv", "suffix": ".csv", "vehicle": "asctec_hummingbird", "flights": ["f0"]}}}
    (tmp_path / "data.yaml").write_text(yaml.safe_dump(spec))
    for name in ("conf", "workflow", "Snakefile"):
        (tmp_path / name).symlink_to(ROOT / name)
    out = subprocess.run([SNAKEMAKE, "--cores", "1", "--config", f"data={tmp_path / 'data.yaml'}",
                          "--", "results/ingest/summary.csv"], cwd=tmp_path, capture_output=True, text=True,
                         env={**os.environ, "QR_RESULTS": str(tmp_path / "results"), "QR_TRACKING": "off"})
    assert out.returncode != 0
    log = (tmp_path / "results" / "logs" / "ingest" / "bad" / "batch0.log").read_text()
    line = next(x for x in log.splitlines() if x.startswith("qr: error: "))
    assert "f0.csv: " in line and "; fix: " in line, log
    assert line in out.stdout + out.stderr and "lost sys.stderr" not in out.stdout + out.stderr
    assert not (tmp_path / "results" / "ingest" / "bad" / "f0.parquet").exists()


def test_a_data_set_whose_vehicle_is_not_there_is_refused_at_the_start_in_one_line(tmp_path):
    """A set's vehicle that names nothing shipped, or a file that is not there: one line naming the data set file,
    the key and the fix (the shipped names), before any job; before, Snakemake reported a missing input of each job."""
    import os

    import yaml

    (tmp_path / "data" / "csv").mkdir(parents=True)
    (tmp_path / "data" / "csv" / "f0.csv").write_text("t\n0\n")
    for name in ("conf", "workflow", "Snakefile"):
        (tmp_path / name).symlink_to(ROOT / name)
    for vehicle, problem in (("hummingbird", "hummingbird is neither a shipped vehicle nor a vehicle file (.yaml)"),
                             ("mine.yaml", f"mine.yaml is not a file ({tmp_path / 'mine.yaml'})")):
        spec = {"name": "mine", "root": str(tmp_path / "data"),
                "sets": {"s": {"dir": "csv", "suffix": ".csv", "vehicle": vehicle, "flights": ["f0"]}}}
        (tmp_path / "data.yaml").write_text(yaml.safe_dump(spec))
        out = subprocess.run([SNAKEMAKE, "--cores", "1", "--config", f"data={tmp_path / 'data.yaml'}"], cwd=tmp_path,
                             capture_output=True, text=True, env={**os.environ, "QR_RESULTS": str(tmp_path / "results")})
        assert out.returncode != 0
        line = f"{tmp_path / 'data.yaml'}: sets.s.vehicle: {problem}; fix: name a shipped vehicle (asctec_hummingbird, "
        assert line in out.stdout + out.stderr, out.stdout + out.stderr
        assert not (tmp_path / "results").exists()
