# Filter: every ingested flight -> state table + NIS report (one job per batch of a set's flights), a NIS
# summary over all flights (and one MLflow run per flight: logged by filter_summary from one process, since
# importing MLflow costs more than filtering a flight), and thesis-style figures (Figs. 4.2-4.8) for one
# chosen flight.
# The Hydra overrides of the filter (conf/filter/) come from conf/workflow.yaml, key `filter`; unless they
# select a filter, it is the one the diagnoses read (qr.estimation.settings.DIAGNOSIS_FILTER), so the
# cross-fit files are theirs and no diagnosis filters a flight again.
from qr.config import selects_filter
from qr.estimation.settings import DIAGNOSIS_FILTER

FILTER = config.get("filter", {})
FILTER_OVERRIDES = list(FILTER.get("overrides", []))
if not selects_filter(FILTER_OVERRIDES):
    FILTER_OVERRIDES.insert(0, f"filter={DIAGNOSIS_FILTER}")
_first = next(iter(SETS))  # default: the first flight of the first set
FIGURE_SET, FIGURE_FLIGHT = FILTER.get("figure_flight", f"{_first}/{SETS[_first]['flights'][0]}").split("/")
FILTER_FIGURES = ["position", "velocity", "acceleration", "quaternion", "angular_velocity",
                  "angular_acceleration", "rotors"]


FILTERED = {  # one flight's filter outputs: what the other rules read
    "states": "results/filter/{set}/{flight}.parquet",
    "nis": "results/filter/{set}/{flight}.nis.json",
    # every airborne segment's matched estimate and its even/odd cross-fitting halves: what the
    # diagnoses read instead of filtering the flight again
    "crossfit": "results/filter/{set}/{flight}.crossfit.parquet",
}

# one job per batch of a set's flights (common.smk: batches), as the ingest
for _set in SETS:
    for _k, _flights in enumerate(batches(_set)):

        rule:
            name:
                batch_rule("filter", _set, _k)
            input:
                flights=[INGESTED.format(set=_set, flight=f) for f in _flights],
                vehicle=vehicle_file(_set),
            output:
                **{key: [path.format(set=_set, flight=f) for f in _flights] for key, path in FILTERED.items()},
            log:
                f"results/logs/filter/{_set}/batch{_k}.log",
            benchmark:
                f"results/benchmarks/filter/{_set}/batch{_k}.tsv"
            params:
                overrides=FILTER_OVERRIDES,
                names=[f"{_set}/{f}" for f in _flights],
            conda:
                "../envs/qr.yaml"
            script:
                "../scripts/filter.py"


rule filter_summary:
    input:
        nis=[p for s in SETS for p in flights_of(s, FILTERED["nis"])],
        states=[p for s in SETS for p in flights_of(s, FILTERED["states"])],
        flights=[p for s in SETS for p in flights_of(s, INGESTED)],
        vehicles=[vehicle_file(s) for s in SETS for _ in SETS[s]["flights"]],
    output:
        table="results/filter/summary.csv",
        markdown="results/filter/summary.md",
    log:
        "results/logs/filter/summary.log",
    benchmark:
        "results/benchmarks/filter/summary.tsv"
    params:
        names=[f"{s}/{f}" for s in SETS for f in SETS[s]["flights"]],
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/filter_summary.py"


rule filter_figures:
    input:
        flight=expand(INGESTED, set=FIGURE_SET, flight=FIGURE_FLIGHT),
        states=expand(FILTERED["states"], set=FIGURE_SET, flight=FIGURE_FLIGHT),
        vehicle=vehicle_file(FIGURE_SET),  # the rotor speeds' unit on the figure's axis
    output:
        [report(f"results/figures/filter_{q}.png", caption="../report/filter_figures.rst", category="Filter")
         for q in FILTER_FIGURES],
    log:
        "results/logs/filter/figures.log",
    benchmark:
        "results/benchmarks/filter/figures.tsv"
    params:
        title=f"{FIGURE_SET}/{FIGURE_FLIGHT}",
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/filter_figures.py"
