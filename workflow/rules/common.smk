# Shared definitions: configuration, data sets, path helpers.
import os
from pathlib import Path

import yaml
from snakemake.utils import validate


configfile: "conf/workflow.yaml"


validate(config, "../schemas/config.schema.yaml")

# After a killed run (SIGKILL, power loss): drop orphaned write-then-rename temporaries, each only if
# the process that left it is gone (qr.procs).  Snakemake's own lock is Snakemake's (`--unlock`).
from qr.config import experiments  # named experiments (conf/experiment/) as one Hydra override
from qr.procs import remove_orphan_temporaries

remove_orphan_temporaries("results")

DATA = yaml.safe_load(open(config["data"]))
DATA_ROOT = Path(os.environ.get("QR_DATA", DATA["root"]))
SETS = {name: dict(DATA["sets"][name]) for name in config["sets"]}
if config.get("flights_per_set"):  # a reduced run (conf/workflow_ci.yaml): the first N flights of each set
    for _s in SETS.values():
        _s["flights"] = _s["flights"][: int(config["flights_per_set"])]


def raw_log(wildcards):
    s = SETS[wildcards.set]
    return str(DATA_ROOT / s["dir"] / wildcards.flight)


def vehicle_file(set_name):
    return f"conf/vehicle/{SETS[set_name]['vehicle']}.yaml"


def flights_of(set_name, pattern):
    return [pattern.format(set=set_name, flight=f) for f in SETS[set_name]["flights"]]


DIAG = config.get("diagnose", {})
DIAG_FIRST = DIAG.get("first", "brushless")
DIAG_CARRY = DIAG.get("carry_to", "payload")


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


LEARNED_VEHICLE = SETS[DIAG_FIRST]["vehicle"] if DIAG_FIRST in SETS else "crazyflie21_brushless"


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
    """(png, caption) for the overview page; directories are the rules' outputs, the files inside them."""
    out = []
    for s in SETS:
        out += [(f"results/diagnosis/{s}/all/figures/residual_vs_effects.png",
                 f"Diagnosis, {s}: held-out residual force and torque of the nominal model (grey) and what "
                 "the named effects explain (red)"),
                (f"results/diagnosis/{s}/all/figures/replay_drift.png",
                 f"Diagnosis, {s}: open-loop replay drift of the nominal and the extended model"),
                (f"results/evaluation/{s}/held_out/figures/rollout_mae.png",
                 f"Rollout, {s}: MAE against the horizon h per model on the held-out flights")]
    out += [("results/figures/sim_tracking.png", "Simulation (thesis Chapter 5): the Bezier trajectory flown by "
             "the nominal, the compensated and the oracle controller"),
            ("results/figures/sim_rmse.png", "Simulation: tracking RMSE per controller and residual model")]
    return out
