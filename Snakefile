# qr workflow: raw logs -> canonical flights -> ... -> results/.
# Stages live in workflow/rules/*.smk; scripts in workflow/scripts/ only call qr.


include: "workflow/rules/scheduler.smk"
include: "workflow/rules/common.smk"
include: "workflow/rules/ingest.smk"
include: "workflow/rules/filter.smk"
include: "workflow/rules/learn.smk"
include: "workflow/rules/diagnose.smk"
include: "workflow/rules/evaluate.smk"
include: "workflow/rules/replay.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/export.smk"
include: "workflow/rules/report.smk"


rule all:
    default_target: True
    input:
        rules.summary.output,
        rules.filter_summary.output,
        rules.filter_figures.output,
        rules.simulate.output,
        rules.stability.output,
        rules.learn_tables.output,
        rules.learn_best.output,
        rules.diagnosis_summary.output,
        rules.evaluation_summary.output,
        rules.generalization_summary.output,
        rules.replay_summary.output,
        rules.overview.output,
        expand(rules.export.output, target=EXPORT_TARGETS),
