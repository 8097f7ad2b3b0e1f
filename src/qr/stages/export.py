"""``qr export``: a vehicle file in the format a simulator reads, and mapping.md (docs/spec/export.md).

Reads the vehicle, builds every file in memory (:func:`qr.export.run`: its named effects through the TRUE
plant's parameters, milliseconds), checks ``--out`` against them and writes them all at once
(:func:`qr.atomic.atomic_dir`): nothing half-written, no file of the user's replaced.
"""

from __future__ import annotations

from pathlib import Path

from .. import __version__


def run_export(vehicle_path, to: str, out, force: bool = False) -> list[Path]:
    """Write ``vehicle_path`` for simulator ``to`` into the folder ``out``; return the paths written."""
    from ..atomic import atomic_dir, write_file
    from ..export import document, export
    from ..outputs import check_out_dir
    from ..vehicle import load_vehicle

    export.exporter(to)  # an unknown --to is said before the vehicle is read
    result = export.run(load_vehicle(vehicle_path), vehicle_path, to, __version__)
    out = check_out_dir(out, inputs=[vehicle_path], force=force, expected=["mapping.md", *result.entries])
    with atomic_dir(out, force=force, command="qr export") as tmp:
        for f in document.files(result):
            write_file(tmp / f.name, f.data)
    return [Path(out) / n.rstrip("/") for n in [*result.entries, "mapping.md"]]
