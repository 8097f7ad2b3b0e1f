"""``qr export``: a vehicle file in the format a simulator reads, and mapping.md (docs/spec/export.md).

Checks ``--out`` before any work, builds every file in memory from the vehicle (its named effects
through the TRUE plant's parameters, :func:`qr.export.mapping.plant_of`), and writes them all at
once (:func:`qr.atomic.atomic_dir`): nothing half-written, no file of the user's replaced.
"""

from __future__ import annotations

import difflib
import importlib
from pathlib import Path

from .. import __version__
from ..errors import QrInputError
from ..export import TARGETS

MODULES = {"rotorpy": "rotorpy", "px4-gz": "px4_gz", "mujoco": "mujoco"}


def target_module(to: str):
    """The exporter of ``--to``; an unknown name is one line naming the known ones."""
    if to not in TARGETS:
        close = difflib.get_close_matches(str(to), TARGETS, n=1)
        raise QrInputError("--to", f"unknown simulator '{to}'" + (f" (did you mean '{close[0]}'?)" if close else ""),
                           f"use one of {', '.join(TARGETS)}")
    return importlib.import_module(f"qr.export.{MODULES[to]}")


def expected_outputs(to: str, vehicle) -> list[str]:
    return ["mapping.md", *target_module(to).outputs(vehicle)]


def run_export(vehicle_path, to: str, out, force: bool = False) -> list[Path]:
    """Write ``vehicle_path`` for simulator ``to`` into the folder ``out``; return the paths written."""
    from ..atomic import atomic_dir, write_text
    from ..export import mapping
    from ..outputs import check_out_dir
    from ..vehicle import load_vehicle

    module = target_module(to)
    vehicle = load_vehicle(vehicle_path)
    out = check_out_dir(out, inputs=[vehicle_path], force=force, expected=expected_outputs(to, vehicle))
    pp = mapping.plant_of(vehicle)
    rows = module.rows(vehicle, pp)
    text = mapping.render(to, str(vehicle_path), vehicle, rows, module.INTRO, __version__, pp)
    with atomic_dir(out, force=force, command="qr export") as tmp:
        names = module.write(tmp, vehicle, pp, str(vehicle_path), __version__)
        write_text(tmp / "mapping.md", text)
    return [Path(out) / n.rstrip("/") for n in [*names, "mapping.md"]]
