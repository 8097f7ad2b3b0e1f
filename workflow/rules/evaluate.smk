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
        split=lambda wc: repeat_split(wc.set),
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
    params:
        split=lambda wc: repeat_split(wc.set),
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


# Generalisation (docs/workflow.md): per set, the held-out splits of the data set's `workflow.generalization.sets`
# (whole trajectory types or time scales held out, or the faster flights: conf/data/*.yaml), each a fold that
# trains what it scores (rule generalization_fold: the training diagnosis with the refinement, the rollout of
# its models, and where `hybrid: true` a residual trained through the rollout); one table beside the repeat
# split (every third flight: the same trajectories) of the rules above.
GEN_DIRS = [f"results/generalization/{s}/{f}" for s, fs in GEN_FOLDS.items() for f in fs]


rule generalization_fold:
    input:
        flights=lambda wc: flights_of(wc.set, INGESTED),
        nis=lambda wc: flights_of(wc.set, FILTERED["nis"]),
        crossfit=lambda wc: flights_of(wc.set, FILTERED["crossfit"]),
        vehicle=diagnosis_vehicle,
    output:
        directory("results/generalization/{set}/{fold}"),
    log:
        "results/logs/evaluate/generalization_{set}_{fold}.log",
    benchmark:
        "results/benchmarks/evaluate/generalization_{set}_{fold}.tsv"
    params:
        fold=lambda wc: GEN_FOLDS[wc.set][wc.fold].to_dict(),
        overrides=lambda wc: diagnosis_overrides(wc.set, extra=EVAL.get("experiments", []),
                                                 extra_overrides=EVAL.get("overrides", [])),
        single=lambda wc: diagnosis_overrides(wc.set, each=True, extra=EVAL.get("experiments", []),
                                              extra_overrides=EVAL.get("overrides", [])),
        residual=["learn.keep_remainder=false", *LEARN.get("residual", []), *GEN.get("residual", [])],
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/generalization_fold.py"


rule generalization_summary:
    input:
        folds=GEN_DIRS,
        repeat=expand(rules.evaluate_held_out.output.evaluation, set=list(SETS)),
        learned=expand(rules.evaluate_learned.output[0], set=list(SETS)),
    output:
        table="results/tables/generalization.csv",
    log:
        "results/logs/evaluate/generalization.log",
    benchmark:
        "results/benchmarks/evaluate/generalization.tsv"
    params:
        names=list(SETS),
        fold_sets=[s for s, fs in GEN_FOLDS.items() for _ in fs],
        skipped=GEN_SKIPPED,
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/generalization_summary.py"
