# Report: the overview page results/report.html opens on (what was diagnosed, the named effects, the gains,
# the rollout, the thesis tables, the main figures with captions), built from the workflow's own tables.

report: "../report/workflow.rst"


def overview_figures():
    """(png, caption) for the overview page; directories are the rules' outputs, the files inside them."""
    out = []
    for s in SETS:
        out += [(f"results/diagnosis/{s}/all/figures/residual_vs_effects.png",
                 f"Diagnosis, {s}: held-out residual force and torque of the nominal model (grey) and what "
                 "the named effects explain (red)"),
                (f"results/diagnosis/{s}/all/figures/replay_drift.png",
                 f"Diagnosis, {s}: open-loop replay drift of the nominal and the extended model"),
                (f"results/evaluation/{s}/held_out/figures/rollout_mae.png",
                 f"Rollout, {s}: MAE against the horizon h per model on the held-out flights")]
    out += [("results/figures/sim_tracking.png", "Simulation (thesis Chapter 5): the Bezier trajectory flown by "
             "the nominal, the compensated and the oracle controller"),
            ("results/figures/sim_rmse.png", "Simulation: tracking RMSE per controller and residual model")]
    return out


rule overview:
    input:
        diagnosis=rules.diagnosis_summary.output.table,
        rollout=rules.evaluation_summary.output.table,
        thesis=[f"results/tables/{t}.csv" for t in LEARN_TABLES],
        sets=expand(rules.diagnose_set.output[0], set=list(SETS)),
        evaluations=expand(rules.evaluate_held_out.output.evaluation, set=list(SETS)),
        sim=[rules.simulate.output.tracking, rules.simulate.output.rmse],
    output:
        report("results/overview.html", caption="../report/overview.rst", category="0. Overview"),
    log:
        "results/logs/report/overview.log",
    params:
        thesis=LEARN_TABLES,
        figures=overview_figures(),
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/overview.py"
