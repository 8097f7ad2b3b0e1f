# Filter: every ingested flight -> state table + NIS report, a NIS summary (and one MLflow run per flight:
# logged by filter_summary from one process, since importing MLflow costs more than filtering a flight),
# over all flights, and thesis-style figures (Figs. 4.2-4.8) for one chosen flight.
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


rule filter:
    input:
        flight=rules.ingest.output[0],
        vehicle=lambda wc: vehicle_file(wc.set),
    output:
        states="results/filter/{set}/{flight}.parquet",
        nis="results/filter/{set}/{flight}.nis.json",
        # every airborne segment's matched estimate and its even/odd cross-fitting halves: what the
        # diagnoses read instead of filtering the flight again
        crossfit="results/filter/{set}/{flight}.crossfit.parquet",
    log:
        "results/logs/filter/{set}/{flight}.log",
    benchmark:
        "results/benchmarks/filter/{set}/{flight}.tsv"
    params:
        overrides=FILTER_OVERRIDES,
        name=lambda wc: f"{wc.set}/{wc.flight}",
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/filter.py"


rule filter_summary:
    input:
        nis=[p for s in SETS for p in flights_of(s, rules.filter.output.nis)],
        states=[p for s in SETS for p in flights_of(s, rules.filter.output.states)],
        flights=[p for s in SETS for p in flights_of(s, rules.ingest.output[0])],
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
        flight=expand(rules.ingest.output[0], set=FIGURE_SET, flight=FIGURE_FLIGHT),
        states=expand(rules.filter.output.states, set=FIGURE_SET, flight=FIGURE_FLIGHT),
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
