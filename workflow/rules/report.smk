# Report: the overview page results/report.html opens on (what was diagnosed, the named effects, the gains,
# the rollout, the thesis tables, the main figures with captions), built from the workflow's own tables.

report: "../report/workflow.rst"


rule overview:
    input:
        diagnosis=rules.diagnosis_summary.output.table,
        rollout=rules.evaluation_summary.output.table,
        generalization=rules.generalization_summary.output.table,
        replay=rules.replay_summary.output.table,
        thesis=[f"results/tables/{t}.csv" for t in LEARN_TABLES],
        sets=expand(rules.diagnose_set.output[0], set=list(SETS)),
        evaluations=expand(rules.evaluate_held_out.output.evaluation, set=list(SETS)),
        sim=[rules.simulate.output.tracking, rules.simulate.output.rmse],
    output:
        report("results/overview.html", caption="../report/overview.rst", category="0. Overview"),
        fragment="results/overview.fragment.html",  # the report's landing page (workflow.rst)
    log:
        "results/logs/report/overview.log",
    params:
        thesis=LEARN_TABLES,
        figures=overview_figures(),
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/overview.py"
