# Shared definitions: configuration, data sets, path helpers.
import os
import re
import sys
from pathlib import Path

import yaml
from snakemake.exceptions import WorkflowError
from snakemake.utils import validate


configfile: "conf/workflow.yaml"


def _under(base: dict, top: dict) -> dict:
    """``top`` merged over ``base``, dict by dict (a list or value in ``top`` replaces ``base``'s)."""
    out = dict(base)
    for k, v in top.items():
        out[k] = _under(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


DATA_FILE = Path(config["data"])
if not DATA_FILE.is_file():
    raise WorkflowError(f"{DATA_FILE}: data set file does not exist; fix: --config data=conf/data/<name>.yaml "
                        "(see docs/workflow.md, 'Your own data set')")
DATA = yaml.safe_load(DATA_FILE.read_text())
validate(DATA, "../schemas/data.schema.yaml")
# the data set's own needs of the workflow (its chain, figure flight, experiments) under the workflow config
config.update(_under(DATA.get("workflow") or {}, dict(config)))
validate(config, "../schemas/config.schema.yaml")

# After a killed run (SIGKILL, power loss): drop orphaned write-then-rename temporaries, each only if
# the process that left it is gone (qr.procs).  Snakemake's own lock is Snakemake's (`--unlock`).
from qr.config import experiments  # named experiments (conf/experiment/) as one Hydra override
from qr.procs import remove_orphan_temporaries
from qr.shipped import shipped_vehicles, vehicle_file as find_vehicle

remove_orphan_temporaries("results")

_env = DATA.get("root_env")
DATA_ROOT = Path(os.environ[_env] if _env and os.environ.get(_env) else DATA["root"])
_unknown = [n for n in config.get("sets") or [] if n not in DATA["sets"]]
if _unknown:
    raise WorkflowError(f"{DATA_FILE}: no set {', '.join(_unknown)} (it has {', '.join(DATA['sets'])}); fix: "
                        "--config sets=[...] with the data set's names, or leave `sets` out to run them all")
SETS = {name: dict(DATA["sets"][name]) for name in (config.get("sets") or DATA["sets"])
        if name not in (config.get("skip_sets") or [])}
if config.get("flights_per_set"):  # a reduced run (conf/workflow_ci.yaml): N flights of each set that differ
    from qr.flightsets import parse_flown, spread  # (in the set's order; without `flown:` the first N)

    for _name, _s in SETS.items():
        _info = parse_flown(_s["flown"], _s["flights"], f"{DATA_FILE}: sets.{_name}.flown") if _s.get("flown") else None
        _s["flights"] = spread(_s["flights"], _info, int(config["flights_per_set"]))


def raw_log(set_name, flight):
    s = SETS[set_name]
    return str(DATA_ROOT / s.get("dir", "") / (flight + s.get("suffix", "")))


FLIGHTS_PER_JOB = int(config["flights_per_job"])  # conf/workflow.yaml


def batches(set_name):
    """The set's flights in consecutive batches of at most `flights_per_job`, as equal as can be: one
    ingest and one filter job each (rules ingest_<set>_<k>, filter_<set>_<k>), so a job's Python,
    imports and compiled kernels start once per batch, not once per flight; several batches per set keep
    both cores busy."""
    flights = SETS[set_name]["flights"]
    n = len(flights)
    k = -(-n // FLIGHTS_PER_JOB)
    return [flights[i * n // k:(i + 1) * n // k] for i in range(k)]


def batch_rule(stage, set_name, k):
    """The name of the rule of a set's k-th batch (a rule name is an identifier)."""
    name = re.sub(r"\W", "_", set_name)
    return f"{stage}_{name}_{k}"


def shipped_vehicle(name):
    """A shipped vehicle's file in this workflow's conf/ (qr.shipped: how a name is found)."""
    return str(find_vehicle(name, conf="conf"))


def vehicle_file(set_name):
    """A shipped vehicle by name (conf/vehicle/), or a vehicle file's path (relative to the data set file)."""
    v = str(SETS[set_name]["vehicle"])
    if v.endswith((".yaml", ".yml")):
        return str(DATA_FILE.parent / v) if not Path(v).is_absolute() else v
    return shipped_vehicle(v)


for _name in SETS:  # a vehicle that is not there: one line at the start, not a missing input of every job
    if not Path(vehicle_file(_name)).is_file():
        _v = SETS[_name]["vehicle"]
        raise WorkflowError(
            f"{DATA_FILE}: sets.{_name}.vehicle: {_v} is " + (f"not a file ({vehicle_file(_name)})"
            if str(_v).endswith((".yaml", ".yml")) else "neither a shipped vehicle nor a vehicle file (.yaml)")
            + f"; fix: name a shipped vehicle ({', '.join(shipped_vehicles())}) or give your vehicle file's path "
            "(relative to the data set file)")


def flights_of(set_name, pattern):
    return [pattern.format(set=set_name, flight=f) for f in SETS[set_name]["flights"]]


DIAG = config.get("diagnose", {})
DIAG_FIRST = DIAG.get("first")  # the chain (a set diagnosed first, its model carried to another): optional
DIAG_CARRY = DIAG.get("carry_to")


def diagnosis_overrides(set_name, each=False, extra=(), extra_overrides=()):
    """Hydra overrides of a set's diagnoses: the named experiments of `diagnose.experiments`, then
    `each_experiments` (a per-flight diagnosis), `carry_experiments` (the carry-to set) and ``extra``;
    the plain `overrides` keys likewise, after them."""
    carry = set_name == DIAG_CARRY and DIAG_FIRST in SETS
    parts = ["", "each_" if each else None, "carry_" if carry else None]
    names = [n for p in parts if p is not None for n in DIAG.get(f"{p}experiments", [])] + list(extra)
    plain = [o for p in parts if p is not None for o in DIAG.get(f"{p}overrides", [])] + list(extra_overrides)
    return experiments(names) + plain


def diagnosis_vehicle(wildcards):
    """The carry-over set is diagnosed with the first set's extended vehicle (rule carry_over)."""
    if wildcards.set == DIAG_CARRY and DIAG_FIRST in SETS:
        return f"results/diagnosis/{DIAG_CARRY}/vehicle.yaml"
    return vehicle_file(wildcards.set)


DIAG_CHECK = DIAG.get("check") if (DIAG.get("check") or {}).get("set") in SETS else None


def check_sets():
    """Name -> diagnosis directory of the cross-check (none when its set is not run)."""
    return {f"{DIAG_CHECK['set']} (check)": f"results/diagnosis/{DIAG_CHECK['set']}/check"} if DIAG_CHECK else {}


MODEL_SET = DIAG_FIRST if DIAG_FIRST in SETS else next(iter(SETS))  # whose models the simulation study flies
LEARNED_VEHICLE = vehicle_file(MODEL_SET)


def stage_sources(wildcards, input):
    """Hydra overrides that switch on the learned-model and extended-vehicle sources."""
    extended = f"{input.diagnosis}/extended_vehicle.yaml"
    return [
        "simulate.sources.learned.enabled=true",
        f"simulate.sources.learned.vehicle={LEARNED_VEHICLE}",
        f"simulate.sources.learned.plant.force.path={input.learned}",
        f"simulate.sources.learned.estimates.learned.path={input.learned}",
        "simulate.sources.extended_vehicle.enabled=true",
        f"simulate.sources.extended_vehicle.vehicle={extended}",
        f"simulate.sources.extended_vehicle.estimates.extended.path={extended}",
    ]


def overview_figures():
    """(png, caption) for the overview page, each caption saying what to look at; directories are the rules'
    outputs, the files inside them."""
    out = []
    for s in SETS:
        out += [(f"results/diagnosis/{s}/all/figures/residual_vs_effects.png",
                 f"Diagnosis, {s}: the held-out force and torque residual of the nominal model (grey), the flights "
                 "one after another (shaded alternately), and what the named effects explain (red). Where red follows "
                 "grey, a named effect accounts for the error; grey left around red is what none explains."),
                (f"results/diagnosis/{s}/all/figures/replay_drift.png",
                 f"Diagnosis, {s}: how far an open-loop replay, driven by the measured rotor speeds, drifts from the "
                 "measured position after each restart; left the RMS over all restarts per axis, right the three "
                 "worst. The extended model (red) should stay below the nominal one (grey) all along."),
                (f"results/evaluation/{s}/held_out/figures/rollout_mae.png",
                 f"Rollout, {s}: mean absolute error against the time ahead on the held-out flights, per model "
                 "(nominal, extended, hybrid as in the rollout table), beside the benchmark's physics baseline "
                 "(rate_frozen, dark dashed). Below that curve a model predicts better; at the right end the gap "
                 "is the table's ratio.")]
    out += [("results/figures/sim_tracking.png", "Simulation (thesis Chapter 5): the Bezier trajectory flown by "
             "the nominal, the compensated and the oracle controller (left), and each one's position error per "
             "axis (right). The closer a compensated controller's error to the oracle's, the better its model of "
             "the disturbance."),
            ("results/figures/sim_rmse.png", "Simulation: position RMSE per residual model and controller (log "
             "scale; hatched: diverged). Lower is better; the oracle, which knows the true disturbance, is the floor.")]
    return out


# ---- the held-out splits (rules evaluate_held_out, generalization_fold: workflow/rules/evaluate.smk) ----

def repeat_split(set_name):
    """The repeat split of a set, with what its flights fly where the data set says (its report then says
    whether the held-out flights repeat training trajectories)."""
    described = bool(SETS[set_name].get("flown"))
    return {"kind": "repeat", "data": str(DATA_FILE) if described else "", "set": set_name if described else ""}


GEN = config.get("generalization", {})


def _generalization_folds():
    """Set -> fold name -> qr.holdout.Fold; and the folds the run's flights cannot make (a subset of a set),
    left out and said so (in the log and under the table)."""
    from qr.errors import QrInputError
    from qr.holdout import folds

    out, skipped = {}, []
    for name, specs in (GEN.get("sets") or {}).items():
        if name not in SETS or not specs:
            continue
        left = []
        try:
            out[name] = {f.name: f for f in folds(specs, SETS[name]["flights"], str(DATA_FILE), name, skipped=left)}
        except QrInputError as e:
            raise WorkflowError(f"{DATA_FILE}: workflow.generalization.sets.{name}: {e}") from None
        for fold, why in left:
            print(f"generalization: {name}/{fold} left out: {why}", file=sys.stderr)
            skipped.append(f"{name}/{fold}: {why}")
    return out, skipped


GEN_FOLDS, GEN_SKIPPED = _generalization_folds()
