# Ingest: every listed raw log -> canonical flight (Parquet), then one summary table.
# One job per batch of a set's flights (common.smk: batches), not per flight: a job's Python start-up
# costs more than reading a log.

INGESTED = "results/ingest/{set}/{flight}.parquet"  # one canonical flight: what the other rules read

for _set in SETS:
    for _k, _flights in enumerate(batches(_set)):

        rule:
            name:
                batch_rule("ingest", _set, _k)
            input:
                raw=[raw_log(_set, f) for f in _flights],
                vehicle=vehicle_file(_set),
            output:
                flights=[INGESTED.format(set=_set, flight=f) for f in _flights],
            log:
                f"results/logs/ingest/{_set}/batch{_k}.log",
            benchmark:
                f"results/benchmarks/ingest/{_set}/batch{_k}.tsv"
            params:
                format=DATA.get("format", "auto"),
            conda:
                "../envs/qr.yaml"
            script:
                "../scripts/ingest.py"


rule summary:
    input:
        flights=[p for s in SETS for p in flights_of(s, INGESTED)],
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
        sets={s: flights_of(s, INGESTED) for s in SETS},
        vehicles={s: vehicle_file(s) for s in SETS},
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/summary.py"
