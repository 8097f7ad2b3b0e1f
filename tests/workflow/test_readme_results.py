"""The README's Results section (qr.report.readme, `make readme-results`): built from hand-made tables in the
workflow's formats, it states their numbers (checked here against hand-computed values), says which split a
held-out number comes from, replaces only what lies between the markers, gives the same text when run twice,
and refuses a README without markers or a results folder without a table in one line, nothing written."""

import json
import math
import re
import subprocess
import sys

import pandas as pd
import pytest

from conftest import ROOT
from qr.report import readme as rr

CI = ROOT / "conf" / "workflow_ci.yaml"


def _results(root, flights=2, residual=None, generalization=False):
    """A results folder in the workflow's formats (columns as qr.stages.*.summary* and the learning tables write
    them), small enough to compute every cell of the block by hand."""
    t, sim = root / "tables", root / "simulation"
    t.mkdir(parents=True)
    sim.mkdir()
    pd.DataFrame([
        {"set": "brushless", "flights": flights, "samples": 1650,
         "named": "linear_drag(kx=0.0125 N s/m, ky=0.0126 N s/m, kz=0.0098 N s/m); blade_flapping(k=0.000694 N m s/m)",
         "nominal_force_rmse": "0.0070 / 0.0042 / 0.0160", "extended_force_rmse": "0.0014 / 0.0012 / 0.0008",
         "noise_force_rmse": "0.0007 / 0.0006 / 0.0004", "nominal_torque_rmse": "1.86e-04 / 3.38e-04 / 2.47e-05",
         "extended_torque_rmse": "4.10e-05 / 1.62e-04 / 1.73e-05", "replay_nominal_m": 0.43,
         "replay_extended_m": 0.16, "remainder": "-"},
        {"set": "payload (check)", "flights": flights, "samples": 1627, "named": "none",
         "nominal_force_rmse": "0.0090 / 0.0130 / 0.0120", "extended_force_rmse": "0.0090 / 0.0130 / 0.0120",
         "noise_force_rmse": "0.0020 / 0.0020 / 0.0010", "nominal_torque_rmse": "3.02e-04 / 3.09e-04 / 3.65e-05",
         "extended_torque_rmse": "3.02e-04 / 3.09e-04 / 3.65e-05", "replay_nominal_m": 0.455,
         "replay_extended_m": 0.455, "remainder": "u"},
    ]).to_csv(t / "diagnosis_summary.csv", index=False)
    (t / "diagnosis_summary.md").write_text("### Diagnoses of the measured flight sets\n")
    roll = []
    for s, n, h, models in (("brushless", 10, 0.5, {"hold": 2.35, "rate_frozen": 1.0, "nominal": 4.22,
                                                    "hybrid": 0.6}),
                            ("payload", 21, 0.49435, {"rate_frozen": 1.0, "nominal": 1.44,
                                                      "hybrid (rollout-trained, carried over)": 0.6})):
        for m, x in models.items():
            roll.append({"set": s, "held-out flights": n, "model": m, "horizon (s)": h,
                         **{c: v for q, k in zip("pvRw", (1, 2, 3, 4))
                            for c, v in ((f"{q}@50", 0.1 * k), (f"{q} / rate_frozen", x * k if x != 1 else 1.0))}})
    pd.DataFrame(roll).to_csv(t / "rollout_held_out.csv", index=False)
    pd.DataFrame([
        {"set": "brushless", "flights": 10, "model": "nominal", "position RMSE (m)": 0.089, "max (m)": 0.14,
         "parts at (s)": 0.88, "attitude RMSE (deg)": 3.35, "rotor speeds RMSE (%)": 3.1, "thrust RMSE (N)": 0.013,
         "position / nominal": 1.0, "attitude / nominal": 1.0, "lost at (s)": None},
        {"set": "brushless", "flights": 10, "model": "hybrid", "position RMSE (m)": 0.69, "max (m)": 1.79,
         "parts at (s)": 0.29, "attitude RMSE (deg)": 47.3, "rotor speeds RMSE (%)": 29.6, "thrust RMSE (N)": 0.18,
         "position / nominal": 0.69 / 0.089, "attitude / nominal": 47.3 / 3.35, "lost at (s)": 1.743},
    ]).to_csv(t / "replay.csv", index=False)
    ann = lambda unit, nominal, rows: pd.DataFrame(  # noqa: E731  (thesis Table 4.2 / 4.3 columns)
        [{"Model No.": 0, "Inputs": "Nominal model", "No. of hidden layers": "-", "No. of hidden layer neurons": "-",
          "Activation function": "-", f"RMSE ({unit})": nominal, "RMSE / nominal (%)": 100.0, "leaks target": False,
          f"thesis RMSE ({unit})": 0.563}]
        + [{"Model No.": no, "Inputs": inp, "No. of hidden layers": 1, "No. of hidden layer neurons": 3,
            "Activation function": "Linear", f"RMSE ({unit})": x, "RMSE / nominal (%)": 100 * x / nominal,
            "leaks target": leaks, f"thesis RMSE ({unit})": 0.25} for no, inp, x, leaks in rows])
    # the row that leaks its target (a_b) has the lowest RMSE: it must not be the one reported
    ann("N", 0.0100, [(4, "v_b, u", 0.0025, False), (14, "v_b, a_b, u", 0.0010, True),
                      (5, "v_b", 0.0040, False)]).to_csv(t / "table_4_2.csv", index=False)
    ann("N m", 6e-05, [(1, "q, u", 4.5e-05, False), (13, "q, α, u", 1e-05, True)]).to_csv(t / "table_4_3.csv",
                                                                                     index=False)
    pd.DataFrame([{"Kernel": k, "Mean": "ridge", "Inputs": "v_b", "RMSE (N)": x, "nominal RMSE (N)": 0.0100,
                   "RMSE / nominal (%)": 100 * x / 0.01, "95 % coverage (%)": c, "train time (s)": 3.3,
                   "training samples": 1012, "sparse (DTC)": False}
                  for k, x, c in (("se_ard", 0.0038, 25.0), ("matern52_ard", 0.0030, 91.5))]
                 ).to_csv(t / "gpr_kernels.csv", index=False)
    for sweep in ("table_4_2", "table_4_3", "gpr_kernels"):
        (root / "learn" / sweep / "runs").mkdir(parents=True)
        (root / "learn" / sweep / "runs" / "row01.json").write_text(json.dumps(
            {"dataset": "results/learn/brushless/dataset.parquet", "split": {"kind": "by_flight", "seed": 0}}))
    (t / "table_3_1.md").write_text("### Table 3.1\n")
    (t / "table_3_1.csv").write_text("Output\n")
    pd.DataFrame([
        {"source": "drag_wind", "vehicle": "asctec-hummingbird", "controller": c, "status": "ok", "rmse": x,
         "ratio_to_nominal": x / 0.0300, "gain_captured": g}
        for c, x, g in (("nominal", 0.0300, 0.0), ("compensated:fit_effects", 0.0050, 1.0),
                        ("compensated:fit_v_q_u", 0.8400, -31.8), ("oracle", 0.0050, 1.0))]
    ).to_csv(sim / "tracking.csv", index=False)
    (sim / "stability.md").write_text("### Stability\n")
    (sim / "stability.csv").write_text("model\n")
    (root / "learn" / "residual" / "brushless").mkdir(parents=True)
    (root / "learn" / "residual" / "brushless" / "training.json").write_text(json.dumps(
        {"config": {"learn": residual or {"epochs": 1, "width": 8, "depth": 1, "stride": 8, "members": 2, "lr": 0.003}}}))
    if generalization:  # issue 33's table: set, split, held_out, model, p, v, R, w, coverage90
        pd.DataFrame([
            {"set": "brushless", "split": "trajectory", "held_out": "time scale 0.5", "model": "physical (refined)",
             "p": 2.06, "v": 2.38, "R": 3.54, "w": 5.49, "coverage90": 0.81},
            {"set": "brushless", "split": "trajectory", "held_out": "time scale 0.5", "model": "hybrid",
             "p": 0.92, "v": 0.89, "R": 0.92, "w": 0.82, "coverage90": 0.9},
            {"set": "brushless", "split": "repeat", "held_out": "every third flight", "model": "hybrid",
             "p": 0.15, "v": 0.11, "R": 0.11, "w": 0.22, "coverage90": None},
        ]).to_csv(t / "generalization.csv", index=False)
    return root


README = "# qr\n\nText before, kept as it is.\n\n<!-- results:begin -->\nold block\n<!-- results:end -->\n\nAfter.\n"


def _run(*args):
    """The command as `make readme-results` runs it, in a fresh process."""
    return subprocess.run([sys.executable, "-m", "qr.report.readme", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT)


def _main(capsys, *args):
    """The same in this process (cheaper): exit status, stdout, stderr."""
    code = rr.main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_the_block_states_the_tables_numbers_with_their_commands_and_splits(tmp_path):
    text = rr.block(_results(tmp_path / "results"), ci_file=CI)
    lines = text.splitlines()
    assert lines[0] == rr.HEADER
    # the config read from the results: the reduced run's residual settings and its 2 flights per set
    assert lines[2].startswith("**Config: ci**: written from the reduced CI workflow")
    assert "Not written by this workflow: `results/tables/generalization.csv`." in lines[2]
    # force residual ÷ noise floor by hand: 0.0070/0.0007 = 10, 0.0042/0.0006 = 7, 0.0160/0.0004 = 40 -> 2, 2, 2
    assert ("| brushless | 2 | linear_drag(kx=0.0125 N s/m, ky=0.0126 N s/m, kz=0.0098 N s/m); "
            "blade_flapping(k=0.000694 N m s/m) | 10 / 7 / 40 → 2 / 2 / 2 | 0.43 → 0.16 |") in lines
    assert "| payload (check) | 2 | none | 4.5 / 6.5 / 12 → 4.5 / 6.5 / 12 | 0.455 → 0.455 |" in lines
    assert "a set marked (check) is the same flights diagnosed again with another vehicle file" in text
    # the rollout: one column per set, the references left out, every third flight said to be interpolation
    assert "| model | brushless (10 held out, 0.5 s) | payload (21 held out, 0.49 s) |" in lines
    assert "| nominal | 4.2 / 8.4 / 13 / 17 | 1.4 / 2.9 / 4.3 / 5.8 |" in lines
    assert "| hybrid | 0.6 / 1.2 / 1.8 / 2.4 | – |" in lines
    assert "| hybrid (rollout-trained, carried over) | – | 0.6 / 1.2 / 1.8 / 2.4 |" in lines
    assert not any(ln.startswith(("| hold ", "| rate_frozen ")) for ln in lines)
    rollout = next(ln for ln in lines if "→ `results/tables/rollout_held_out.csv`" in ln)
    assert rollout.startswith("`snakemake --cores 2 results/tables/rollout_held_out.csv --configfile "
                              "conf/workflow_ci.yaml` → `results/tables/rollout_held_out.csv`.")
    assert "h = 50 steps" in rollout and "interpolation (same trajectories)" in rollout
    # the replay: ratios over the nominal model, and when a model was lost; interpolation said too
    assert "| model | brushless (10 flights) |" in lines
    assert "| hybrid | 0.69 m (7.8×), 47.3° (14×), lost at 1.74 s |" in lines
    assert "interpolation (same trajectories)" in next(ln for ln in lines if "→ `results/tables/replay.csv`" in ln)
    # learning: the best row that does not leak its target (row 4, not row 14), the best GPR kernel
    assert "| f_a (N) | 0.01 | ANN [v_b, u], 1 × 3 Linear | 0.0025 (25 %) | – |" in lines
    assert "| τ_a (N m) | 6e-05 | ANN [q, u], 1 × 3 Linear | 4.5e-05 (75 %) | – |" in lines
    assert "| f_a (N) | 0.01 | GPR matern52_ard [v_b] | 0.003 (30 %) | 91.5 % |" in lines
    learn = next(ln for ln in lines if "`results/tables/gpr_kernels.csv`. `qr learn`" in ln)
    assert "on the brushless flights" in learn and "split `by_flight`" in learn and "interpolation" in learn
    # no published figure beside a number: the thesis columns of the tables are not in the block
    assert "0.563" not in text and "thesis RMSE" not in text
    # the simulation: a model worse than none is said so, with its ratio
    assert ("| drag_wind | asctec-hummingbird | 0.03 | 0.005 | fit_effects 0.005 m (100 %); fit_v_q_u 0.84 m "
            "(worse than no model: 28× the nominal RMSE) |") in lines
    assert lines[-1] == "Also in `results/`: simulation/stability.md, tables/table_3_1.md."
    assert rr.parse_block(f"{rr.BEGIN}\n{text}{rr.END}")["sources"] == [
        "results/tables/diagnosis_summary.csv", "results/tables/rollout_held_out.csv", "results/tables/replay.csv",
        "results/tables/table_4_2.csv", "results/tables/table_4_3.csv", "results/tables/gpr_kernels.csv",
        "results/simulation/tracking.csv"]


def test_the_generalisation_table_comes_first_among_the_rollouts_titled_with_what_was_held_out(tmp_path):
    text = rr.block(_results(tmp_path / "results", generalization=True), ci_file=CI)
    lines = text.splitlines()
    assert "Every table this block knows was written." in lines[2]
    titles = rr.parse_block(f"{rr.BEGIN}\n{text}{rr.END}")["titles"]
    assert titles[1] == "Generalisation: trajectories never flown in training, repeated trajectories held out"
    assert titles[2] == "Multi-step rollout on held-out flights"
    assert "| set: held out (split) | physical (refined) | hybrid |" in lines
    assert ("| brushless: time scale 0.5 (`trajectory`) | 2.1 / 2.4 / 3.5 / 5.5 (81 %) | 0.92 / 0.89 / 0.92 / "
            "0.82 (90 %) |") in lines
    assert "| brushless: every third flight (`repeat`) | – | 0.15 / 0.11 / 0.11 / 0.22 |" in lines
    line = next(ln for ln in lines if "→ `results/tables/generalization.csv`" in ln)
    assert "`trajectory`: whole trajectory types or time scales held out" in line
    assert "`repeat`: every third flight" in line and "interpolation (same trajectories)" in line


def test_the_config_is_read_from_the_results_or_given(tmp_path):
    full = _results(tmp_path / "full", flights=30, residual={"epochs": 60, "width": 32, "depth": 2, "stride": 4})
    assert rr.block(full, ci_file=CI).splitlines()[2].startswith("**Config: full**: written from the full workflow")
    assert "`snakemake --cores 2 results/tables/replay.csv`" in rr.block(full, ci_file=CI)
    # one part of the reduced config's signature only (its residual settings on 30 flights per set): not guessed
    mixed = _results(tmp_path / "mixed", flights=30)
    with pytest.raises(rr.ReadmeError, match="cannot tell from the results which workflow config wrote them"):
        rr.block(mixed, ci_file=CI)
    assert rr.block(mixed, config_name="full", ci_file=CI).splitlines()[2].startswith("**Config: full**")
    assert "**Config: lab-b**" in rr.block(mixed, config_name="lab-b", ci_file=CI)


def test_only_the_block_is_replaced_and_twice_gives_the_same_readme(tmp_path):
    results = _results(tmp_path / "results")
    readme = tmp_path / "README.md"
    readme.write_text(README)
    r = _run("--readme", readme, "--results", results, "--ci-config", CI)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"{readme}: results block rewritten (config ci, 5 tables)"
    first = readme.read_text()
    head, rest = README.split("old block\n")
    assert first == head + rr.block(results, ci_file=CI) + rest  # before and after the markers byte for byte
    r = _run("--readme", readme, "--results", results, "--ci-config", CI)
    assert r.returncode == 0 and "unchanged" in r.stdout and readme.read_text() == first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["README.md", "results"]  # no temporary left


@pytest.mark.parametrize("text, problem", [
    ("# qr\n\nno markers here\n", "no results markers"),
    ("# qr\n<!-- results:end -->\nx\n<!-- results:begin -->\n", "(1 begin, 1 end)"),
    ("# qr\n<!-- results:begin -->\n<!-- results:begin -->\n<!-- results:end -->\n", "(2 begin, 1 end)"),
])
def test_a_readme_without_its_markers_is_refused_untouched(tmp_path, capsys, text, problem):
    results = _results(tmp_path / "results")
    readme = tmp_path / "README.md"
    readme.write_text(text)
    code, out, err = _main(capsys, "--readme", readme, "--results", results, "--ci-config", CI)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith(f"readme-results: error: {readme}: ")
    assert problem in err and "fix: put a line <!-- results:begin -->" in err
    assert readme.read_text() == text


def test_a_missing_table_is_refused_and_nothing_is_written(tmp_path, capsys):
    results = _results(tmp_path / "results")
    (results / "tables" / "replay.csv").unlink()
    readme = tmp_path / "README.md"
    readme.write_text(README)
    code, out, err = _main(capsys, "--readme", readme, "--results", results, "--ci-config", CI)
    assert code == 2 and err.count("\n") == 1
    assert f"{results / 'tables' / 'replay.csv'}: missing (1 of the block's tables absent" in err
    assert "fix: run the workflow first" in err
    assert readme.read_text() == README
    # a table in another format than the script reads: one line too, nothing written
    (results / "tables" / "replay.csv").write_text("set,flights,model\nbrushless,1,nominal\n")
    code, out, err = _main(capsys, "--readme", readme, "--results", results, "--ci-config", CI)
    assert code == 2 and err.count("\n") == 1 and "a table lacks the column 'position RMSE (m)'" in err
    assert readme.read_text() == README
    assert sorted(p.name for p in tmp_path.iterdir()) == ["README.md", "results"]


def test_the_readme_is_short_and_its_results_block_is_the_scripts_output():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250, "README.md has more than 250 lines"
    info = rr.parse_block(text)  # starts with the script's header line naming the command
    assert info["config"] in ("ci", "full"), info
    assert {f"results/{rel}" for rel in rr.REQUIRED.values()} <= set(info["sources"])
    assert info["titles"][0] == "What the nominal model gets wrong, per flight set"
    inner = text[text.index(rr.BEGIN):text.index(rr.END)]
    assert "make readme-results" in inner.splitlines()[1]
    # no project history outside docs/: no issue numbers, commit hashes or "before commit"
    outside = text.replace(inner, "")
    assert not [w for w in ("issue ", "Issue ", "before commit", "commit ") if w in outside]


def test_the_commands_the_readme_block_prints_are_valid_snakemake_invocations():
    """Each table's command, run as printed (a dry run): the targets before --configfile, which would take
    them for config files."""
    text = (ROOT / "README.md").read_text()
    commands = set(re.findall(r"^`(snakemake [^`]+)` → ", text[text.index(rr.BEGIN):text.index(rr.END)], re.M))
    assert len(commands) == 6, commands  # one per table: diagnosis, generalisation, rollout, replay, learn, simulate
    learn = next(c for c in commands if "gpr_kernels.csv" in c).split()
    r = subprocess.run([str(ROOT / ".venv" / "bin" / "snakemake"), "-n", "--nolock", *learn[1:]], cwd=ROOT,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]


def test_make_readme_results_runs_the_script():
    r = subprocess.run(["make", "-n", "readme-results", "CONFIG=ci"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0 and "-m qr.report.readme --config-name 'ci'" in r.stdout


def test_the_goal_lines_state_met_or_not_with_the_numbers_that_decide():
    """Hand-made tables: the physical model meets ≤ 1.0 on one hold-out and not on the other (ω 1.3 there);
    the rollout-trained hybrid is under 0.7 everywhere but worse than the physical model on v in the second
    hold-out; the repeat split is no hold-out of a new trajectory and is left out.  Replay: the extended model
    at 0.44× / 0.40× with 1.2 % rotor speeds meets its goal, the hybrid at 0.56× attitude does not; the payload
    at 0.09 m against 0.04 m (2.25×) does not."""
    g = pd.DataFrame([
        {"set": "b", "split": "speed", "held_out": "0.6-0.5", "model": "physical (refined)", "p": 0.5, "v": 0.47, "R": 0.48, "w": 0.92},
        {"set": "b", "split": "speed", "held_out": "0.6-0.5", "model": "hybrid (rollout-trained)", "p": 0.3, "v": 0.3, "R": 0.3, "w": 0.5},
        {"set": "p", "split": "trajectory", "held_out": "sideways", "model": "physical (refined)", "p": 0.9, "v": 0.2, "R": 0.9, "w": 1.3},
        {"set": "p", "split": "trajectory", "held_out": "sideways", "model": "hybrid (rollout-trained)", "p": 0.6, "v": 0.25, "R": 0.6, "w": 0.6},
        {"set": "p", "split": "repeat", "held_out": "every third", "model": "physical (refined)", "p": 9, "v": 9, "R": 9, "w": 9},
    ])
    assert rr.generalization_goals(g)[:2] + rr.generalization_goals(g)[-1:] == [
        "- Goal, the refined physical model ≤ 1 × `rate_frozen` on p, v, R and ω: met on 1 of 2 hold-outs; not met "
        "on p sideways (`trajectory`): ω 1.3.",
        "- Goal, the rollout-trained hybrid ≤ 0.7 × `rate_frozen` on all four and never worse than the physical "
        "model under it: met on 1 of 2 hold-outs; not met on p sideways (`trajectory`): p 0.6, worse than the "
        "physical model on v.", ""]
    # the band's coverage: 0.91 inside 80–97 %, 0.62 below it; the repeat split's band (0.5) is no hold-out
    g["coverage90"] = [math.nan, 0.91, math.nan, 0.62, 0.5]
    assert rr.generalization_goals(g)[2] == (
        "- Goal, the 90 % band covers 80–97 % of the held-out samples: met on 1 of 2 banded models on hold-outs; "
        "not met on p sideways (`trajectory`), hybrid (rollout-trained): 62 %.")
    r = pd.DataFrame([
        {"set": "brushless", "model": "nominal", "position RMSE (m)": 0.09, "position / nominal": 1.0, "attitude / nominal": 1.0, "rotor speeds RMSE (%)": 3.1},
        {"set": "brushless", "model": "extended", "position RMSE (m)": 0.04, "position / nominal": 0.44, "attitude / nominal": 0.40, "rotor speeds RMSE (%)": 1.2},
        {"set": "brushless", "model": "hybrid", "position RMSE (m)": 0.037, "position / nominal": 0.41, "attitude / nominal": 0.56, "rotor speeds RMSE (%)": 1.8},
        {"set": "payload", "model": "extended", "position RMSE (m)": 0.09, "position / nominal": 1.0, "attitude / nominal": 1.0, "rotor speeds RMSE (%)": 2.0},
    ])
    lines = rr.replay_goals(r)
    assert lines[0].endswith("extended met (position 0.44×, attitude 0.4× the nominal's, rotor speeds 1.2 %); hybrid "
                             "not met (position 0.41×, attitude 0.56× the nominal's, rotor speeds 1.8 %).")
    assert lines[1].endswith("not met (0.09 m against 0.04 m, 2.2×).")
