# Evaluate: the rollout yardstick (docs/spec/evaluate.md) on flights held out by flight: every
# third flight of a set is held out, the others are diagnosed, and `qr evaluate` scores the nominal,
# the extended, the refined and the hybrid vehicle on the held-out ones beside the references hold and
# rate_frozen (rule evaluate_learned: the rollout-trained residuals on the same flights).
# Its training diagnosis adds the named experiments of conf/workflow.yaml's `evaluate.experiments`.

EVAL = config.get("evaluate", {})


rule evaluate_held_out:
    input:
        flights=lambda wc: flights_of(wc.set, INGESTED),
        nis=lambda wc: flights_of(wc.set, FILTERED["nis"]),
        crossfit=lambda wc: flights_of(wc.set, FILTERED["crossfit"]),
        vehicle=diagnosis_vehicle,
    output:
        diagnosis=directory("results/evaluation/{set}/training_diagnosis"),
        evaluation=directory("results/evaluation/{set}/held_out"),
    log:
        "results/logs/evaluate/{set}.log",
    benchmark:
        "results/benchmarks/evaluate/{set}.tsv"
    priority: CHAIN_PRIORITY  # learn.smk
    params:
        overrides=lambda wc: diagnosis_overrides(wc.set, extra=EVAL.get("experiments", []),
                                                 extra_overrides=EVAL.get("overrides", [])),
        single=lambda wc: diagnosis_overrides(wc.set, each=True, extra=EVAL.get("experiments", []),
                                              extra_overrides=EVAL.get("overrides", [])),
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/evaluate_held_out.py"


# The rollout-trained residuals (rule learn_residual; the carry-to set: carried over and fine-tuned) on the
# same held-out flights.
rule evaluate_learned:
    input:
        flights=lambda wc: flights_of(wc.set, INGESTED),
        nis=lambda wc: flights_of(wc.set, FILTERED["nis"]),
        crossfit=lambda wc: flights_of(wc.set, FILTERED["crossfit"]),
        vehicle=diagnosis_vehicle,
        residual=lambda wc: rules.learn_residual.output[0].format(set=wc.set),
        carried=lambda wc: f"results/learn/carried/{wc.set}" if wc.set == RESIDUAL_CARRY else [],
    output:
        directory("results/evaluation/{set}/learned"),
    log:
        "results/logs/evaluate/{set}_learned.log",
    benchmark:
        "results/benchmarks/evaluate/{set}_learned.tsv"
    priority: CHAIN_PRIORITY  # learn.smk
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/evaluate_learned.py"


rule evaluation_summary:
    input:
        sets=expand(rules.evaluate_held_out.output.evaluation, set=list(SETS)),
        learned=expand(rules.evaluate_learned.output[0], set=list(SETS)),
    output:
        table="results/tables/rollout_held_out.csv",
    log:
        "results/logs/evaluate/summary.log",
    benchmark:
        "results/benchmarks/evaluate/summary.tsv"
    params:
        names=list(SETS),
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/evaluation_summary.py"
