# Learning the residual (thesis Chapters 3-4): filtered flights -> learning table -> named Hydra sweeps
# (MLflow parent + child runs) -> the thesis's Tables 3.1, 3.2, 4.2, 4.3 with our numbers.

LEARN_SET = MODEL_SET  # the set whose models the simulation flies (the chain's first; else the first set)
LEARN_SWEEPS = ["table_4_2", "table_4_3", "gpr_kernels"]
LEARN_TABLES = ["table_3_1", "table_3_2", "table_4_2", "table_4_3", "gpr_kernels"]
# Extra Hydra overrides (conf/workflow.yaml, key `learn`): `overrides` for every sweep, `sweeps.<name>` for one
# (a reduced run picks rows with e.g. `learn.row=4,14`; see conf/workflow_ci.yaml).
LEARN = config.get("learn", {})
RESIDUAL_CARRY = DIAG_CARRY if DIAG_CARRY in SETS and DIAG_FIRST in SETS else None  # fine-tunes a carried network


rule learn_dataset:
    input:
        # the full-flight estimates of the cross-fit files: the states the diagnosis labels from
        estimates=lambda wc: flights_of(wc.set, FILTERED["crossfit"]),
        vehicle=lambda wc: vehicle_file(wc.set),
    output:
        "results/learn/{set}/dataset.parquet",
    log:
        "results/logs/learn/{set}/dataset.log",
    benchmark:
        "results/benchmarks/learn/{set}/dataset.tsv"
    params:
        flights=lambda wc: SETS[wc.set]["flights"],
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/learn_dataset.py"


rule learn_sweep:
    input:
        dataset=f"results/learn/{LEARN_SET}/dataset.parquet",
        sweep="conf/sweep/{sweep}.yaml",
        configs=["conf/learn/default.yaml", "conf/split/by_flight.yaml", "conf/model/ann.yaml", "conf/model/gpr.yaml"],
    output:
        "results/learn/{sweep}/runs.csv",
    log:
        "results/logs/learn/{sweep}.log",
    benchmark:
        "results/benchmarks/learn/{sweep}.tsv"
    threads: LEARN.get("threads", 2)  # joblib processes of the sweep; 1 runs its jobs in the sweep's own process
    params:
        overrides=lambda wc: [*LEARN.get("overrides", []), *LEARN.get("sweeps", {}).get(wc.sweep, [])],
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/learn_sweep.py"


rule learn_tables:
    input:
        expand(rules.learn_sweep.output[0], sweep=LEARN_SWEEPS),
    output:
        **{t: f"results/tables/{t}.csv" for t in LEARN_TABLES},
        **{f"{t}_md": f"results/tables/{t}.md" for t in LEARN_TABLES},
    log:
        "results/logs/learn/tables.log",
    benchmark:
        "results/benchmarks/learn/tables.tsv"
    params:
        sweeps={s: f"results/learn/{s}" for s in LEARN_SWEEPS},
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/learn_tables.py"


rule learn_best:
    input:
        force=expand(rules.learn_sweep.output[0], sweep="table_4_2"),
        torque=expand(rules.learn_sweep.output[0], sweep="table_4_3"),
    output:
        force=directory("results/learn/best/f_a"),
        torque=directory("results/learn/best/tau_a"),
    log:
        "results/logs/learn/best.log",
    benchmark:
        "results/benchmarks/learn/best.tsv"
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/learn_best.py"


# The residual chain (training diagnosis -> residual -> carried -> fine-tuned -> its rollout) is the run's
# longest serial path: its jobs go first when two are ready.
CHAIN_PRIORITY = 10


# A residual trained through the rollout (qr learn residual, docs/spec/hybrid.md) on a set's training flights
# (every third flight held out, as rule evaluate_held_out holds it out), on top of the physical part of that
# rule's extended vehicle (the refined one, `physical (refined)`).  The chain's carry-to set (the payload)
# starts from the first set's network carried over (rule carry_residual) and fine-tunes it.
rule learn_residual:
    input:
        flights=lambda wc: flights_of(wc.set, INGESTED),
        nis=lambda wc: flights_of(wc.set, FILTERED["nis"]),
        crossfit=lambda wc: flights_of(wc.set, FILTERED["crossfit"]),
        # (a function: rule evaluate_held_out is defined in evaluate.smk, included after this file)
        diagnosis=lambda wc: rules.evaluate_held_out.output.diagnosis.format(set=wc.set),
        carried=lambda wc: f"results/learn/carried/{wc.set}" if wc.set == RESIDUAL_CARRY else [],
        config="conf/learn/residual.yaml",
    output:
        directory("results/learn/residual/{set}"),
    log:
        "results/logs/learn/residual_{set}.log",
    benchmark:
        "results/benchmarks/learn/residual_{set}.tsv"
    priority: CHAIN_PRIORITY
    params:
        overrides=["learn.keep_remainder=false", *LEARN.get("residual", [])],
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/learn_residual.py"


# The first set's rollout-trained network on the carry-to set's own refined physical model (no training).
if RESIDUAL_CARRY:

    rule carry_residual:
        input:
            diagnosis=lambda wc: rules.evaluate_held_out.output.diagnosis.format(set=RESIDUAL_CARRY),
            residual=f"results/learn/residual/{DIAG_FIRST}",
        output:
            directory(f"results/learn/carried/{RESIDUAL_CARRY}"),
        log:
            "results/logs/learn/residual_carried.log",
        benchmark:
            "results/benchmarks/learn/residual_carried.tsv"
        priority: CHAIN_PRIORITY
        conda:
            "../envs/qr.yaml"
        script:
            "../scripts/carry_residual.py"
