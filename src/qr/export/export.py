"""``qr.export.run(vehicle, vehicle_path, to, version) -> Export``: an export built in memory, every file of it.

The target's module (:mod:`.rotorpy`, :mod:`.px4_gz`, :mod:`.mujoco`) turns the TRUE plant's parameters
(:func:`.mapping.plant_of`) into its files and the rows of ``mapping.md``; :func:`.document.mapping_md`
writes ``mapping.md`` of the result; the stage (:mod:`qr.stages.export`) writes them all in one folder.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass

from ..errors import QrInputError
from . import mapping, mujoco, px4_gz, rotorpy
from .mapping import File, Row

MODULES = {"rotorpy": rotorpy, "px4-gz": px4_gz, "mujoco": mujoco}  # --to -> its module
TARGETS = tuple(MODULES)


def exporter(to: str):
    """The module of simulator ``to``; an unknown name is one line naming the known ones."""
    if to not in TARGETS:
        close = difflib.get_close_matches(str(to), TARGETS, n=1)
        raise QrInputError("--to", f"unknown simulator '{to}'" + (f" (did you mean '{close[0]}'?)" if close else ""),
                           f"use one of {', '.join(TARGETS)}")
    return MODULES[to]


@dataclass(frozen=True)
class Export:
    """A vehicle file for one simulator: its files and what each number of the vehicle became there."""

    target: str  # the simulator (--to)
    vehicle: str  # the vehicle's name
    vehicle_path: str  # the vehicle file as given
    version: str  # qr's, written into the files
    intro: tuple[str, ...]  # mapping.md's paragraph on the simulator's files
    symbols: str  # mapping.md's line that defines the formulas' symbols
    rows: tuple[Row, ...]  # mapping.md's table: every key and named effect of the vehicle file
    files: tuple[File, ...]  # the simulator's files (mapping.md aside: document.mapping_md)

    @property
    def entries(self) -> tuple[str, ...]:
        """The names the simulator's files take in the export folder (mapping.md aside); a folder's ends in ``/``."""
        return tuple(dict.fromkeys(f.name.split("/")[0] + "/" if "/" in f.name else f.name for f in self.files))


def run(vehicle, vehicle_path, to: str, version: str) -> Export:
    """``vehicle`` (read from ``vehicle_path``) for simulator ``to``: every file in memory, nothing written."""
    module = exporter(to)
    pp = mapping.plant_of(vehicle)
    path = str(vehicle_path)
    return Export(to, vehicle.name, path, version, tuple(module.INTRO), mapping.symbols(vehicle, pp),
                  tuple(module.rows(vehicle, pp)), tuple(module.files(vehicle, pp, path, version)))
