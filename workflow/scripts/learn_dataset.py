"""Snakemake rule `learn_dataset`: the filtered flights of one set -> one learning table."""
import sys

import pandas as pd

from qr import datasets
from qr.vehicle import load_vehicle

with open(snakemake.log[0], "w") as log:
    sys.stderr = log
    states = {f: pd.read_parquet(p) for f, p in zip(snakemake.params.flights, snakemake.input.states)}
    table = datasets.build_table(states, load_vehicle(snakemake.input.vehicle))
    datasets.write_table(table, snakemake.output[0])
