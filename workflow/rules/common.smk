# Shared definitions: configuration, data sets, path helpers.
import os
from pathlib import Path

import yaml
from snakemake.utils import validate


configfile: "conf/workflow.yaml"


validate(config, "../schemas/config.schema.yaml")

DATA = yaml.safe_load(open(config["data"]))
DATA_ROOT = Path(os.environ.get("QR_DATA", DATA["root"]))
SETS = {name: DATA["sets"][name] for name in config["sets"]}


def raw_log(wildcards):
    s = SETS[wildcards.set]
    return str(DATA_ROOT / s["dir"] / wildcards.flight)


def vehicle_file(set_name):
    return f"conf/vehicle/{SETS[set_name]['vehicle']}.yaml"


def flights_of(set_name, pattern):
    return [pattern.format(set=set_name, flight=f) for f in SETS[set_name]["flights"]]
