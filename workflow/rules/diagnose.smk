# Diagnose: each measured flight alone, each flight set together, and the engineer's chain
# (the no-payload set first; its extended vehicle, with the payload frame's mass, is the
# nominal model of the payload set) with its cross-check (diagnose.check in conf/workflow.yaml).
# Outputs under results/diagnosis/ and results/tables/.


rule diagnose_set:
    input:
        flights=lambda wc: flights_of(wc.set, INGESTED),
        nis=lambda wc: flights_of(wc.set, FILTERED["nis"]),
        crossfit=lambda wc: flights_of(wc.set, FILTERED["crossfit"]),
        vehicle=diagnosis_vehicle,
    output:
        directory("results/diagnosis/{set}/all"),
    log:
        "results/logs/diagnose/{set}_all.log",
    benchmark:
        "results/benchmarks/diagnose/{set}_all.tsv"
    params:
        overrides=lambda wc: diagnosis_overrides(wc.set),
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/diagnose_set.py"


rule diagnose_each:
    input:
        flights=lambda wc: flights_of(wc.set, INGESTED),
        nis=lambda wc: flights_of(wc.set, FILTERED["nis"]),
        crossfit=lambda wc: flights_of(wc.set, FILTERED["crossfit"]),
        vehicle=diagnosis_vehicle,
    output:
        flights=directory("results/diagnosis/{set}/flights"),
        table="results/tables/diagnosis_flights_{set}.csv",
    log:
        "results/logs/diagnose/{set}_flights.log",
    benchmark:
        "results/benchmarks/diagnose/{set}_flights.tsv"
    params:
        overrides=lambda wc: diagnosis_overrides(wc.set, each=True),
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/diagnose_each.py"


rule carry_over:
    input:
        first=expand(rules.diagnose_set.output[0], set=DIAG_FIRST),
        base=vehicle_file(DIAG_CARRY) if DIAG_CARRY in SETS else [],
    output:
        f"results/diagnosis/{DIAG_CARRY}/vehicle.yaml",
    log:
        "results/logs/diagnose/carry_over.log",
    benchmark:
        "results/benchmarks/diagnose/carry_over.tsv"
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/carry_over.py"


rule diagnose_check:
    input:
        flights=lambda wc: flights_of(wc.set, INGESTED),
        nis=lambda wc: flights_of(wc.set, FILTERED["nis"]),
        crossfit=lambda wc: flights_of(wc.set, FILTERED["crossfit"]),
        vehicle=lambda wc: shipped_vehicle(DIAG_CHECK["vehicle"]),
    output:
        directory("results/diagnosis/{set}/check"),
    log:
        "results/logs/diagnose/{set}_check.log",
    benchmark:
        "results/benchmarks/diagnose/{set}_check.tsv"
    params:
        overrides=lambda wc: experiments([*DIAG.get("experiments", []), *DIAG_CHECK.get("experiments", [])])
        + [*DIAG.get("overrides", []), *DIAG_CHECK.get("overrides", [])],
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/diagnose_set.py"


rule diagnosis_summary:
    input:
        sets=expand(rules.diagnose_set.output[0], set=list(SETS)),
        checks=list(check_sets().values()),
        each=expand(rules.diagnose_each.output.table, set=list(SETS)),
    output:
        table="results/tables/diagnosis_summary.csv",
    log:
        "results/logs/diagnose/summary.log",
    benchmark:
        "results/benchmarks/diagnose/summary.tsv"
    params:
        names=list(SETS) + list(check_sets()),
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/diagnosis_summary.py"
