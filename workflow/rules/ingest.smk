# Ingest: every listed raw log -> canonical flight (Parquet), then one summary table.


rule ingest:
    input:
        raw=raw_log,
        vehicle=lambda wc: vehicle_file(wc.set),
    output:
        "results/ingest/{set}/{flight}.parquet",
    log:
        "results/logs/ingest/{set}/{flight}.log",
    benchmark:
        "results/benchmarks/ingest/{set}/{flight}.tsv"
    params:
        format=DATA.get("format", "auto"),
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/ingest.py"


rule summary:
    input:
        flights=[p for s in SETS for p in flights_of(s, rules.ingest.output[0])],
        vehicles=[vehicle_file(s) for s in SETS],
    output:
        table="results/ingest/summary.csv",
        by_set="results/ingest/summary_by_set.csv",
        figure=report("results/figures/ingest_residual_z.png", caption="../report/ingest_residual_z.rst",
                      category="Ingest"),
    log:
        "results/logs/ingest/summary.log",
    benchmark:
        "results/benchmarks/ingest/summary.tsv"
    params:
        sets={s: flights_of(s, rules.ingest.output[0]) for s in SETS},
        vehicles={s: vehicle_file(s) for s in SETS},
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/summary.py"
