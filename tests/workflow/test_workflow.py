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
