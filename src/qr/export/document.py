"""``mapping.md`` of an :class:`qr.export.export.Export`: what each number of the vehicle became in the
simulator's files (the one writer of that document)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .mapping import APPROXIMATE, EXACT, IMPOSSIBLE, File

if TYPE_CHECKING:
    from .export import Export


def mapping_md(e: Export) -> str:
    """The rows of ``e`` as a table, after a count of them, the simulator's paragraph and the formulas' symbols."""
    counts = {s: sum(r.status == s for r in e.rows) for s in (EXACT, APPROXIMATE, IMPOSSIBLE)}
    lines = [f"# {e.vehicle} for {e.target}: the mapping", "",
             f"Written by `qr export {e.vehicle_path} --to {e.target}` (qr {e.version}). {len(e.rows)} items: "
             f"{counts[EXACT]} exact, {counts[APPROXIMATE]} approximate, {counts[IMPOSSIBLE]} impossible.", "",
             *e.intro, "", e.symbols, "",
             "| qr item | qr value | simulator key | simulator value | formula | mapping | conversion, condition or size |",
             "|---|---|---|---|---|---|---|"]
    for r in e.rows:
        lines.append(f"| {r.item} | {r.qr_value} | {r.key} | {r.value} | {r.formula or '-'} | {r.status} | {r.note} |")
    return "\n".join(lines) + "\n"


def files(e: Export) -> tuple[File, ...]:
    """Every file of the export folder: the simulator's, then ``mapping.md``."""
    return (*e.files, File("mapping.md", mapping_md(e)))
