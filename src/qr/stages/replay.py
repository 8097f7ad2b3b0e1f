"""Stage ``replay``: ``qr replay`` (docs/spec/replay.md): reads the flights and vehicles, runs
:func:`qr.replay.run`, writes ``replay.json``, ``report.md`` and ``figures/`` at once (checked first, built in a
temporary folder) and tracks the run (experiment ``qr-replay``)."""

from __future__ import annotations

import sys
from pathlib import Path

OUTPUTS = ("replay.json", "report.md", "figures/")


def run_replay(flights, vehicles, controller: str, out, overrides=(), force: bool = False, labels=None,
               track: str | None = None, log=None) -> dict:
    """Replay ``flights`` with each of ``vehicles`` under ``controller``; write ``out``; the document."""
    from ..errors import QrInputError
    from ..intake import shown
    from ..outputs import check_out_dir

    out = check_out_dir(out, inputs=[*flights, *vehicles], force=force, expected=OUTPUTS)
    from ..replay.logs import read_replay_log
    from ..vehicle import load_vehicle

    say = log or (lambda msg: print(f"qr replay: {msg}", file=sys.stderr))
    keys = shown(vehicles)  # a vehicle's key: its file's name (its path where two clash)
    if len(set(keys)) < len(keys):
        raise QrInputError(keys[0], "the same vehicle file is given twice", "give each --vehicle once")
    vehs = [load_vehicle(v) for v in vehicles]
    from ..replay.settings import compose_replay

    cfg, settings, given = compose_replay(controller, overrides)
    logs = [read_replay_log(f, vehs[0]) for f in flights]
    from ..atomic import atomic_dir, write_json, write_text
    from ..replay import document, report
    from ..replay.registry import controllers_for
    from ..replay.replay import run

    result = run(logs, vehs, keys, list(labels or keys), controllers_for(controller, cfg["controller"], given), settings, say)
    doc = document.document(result, {"replay": settings.to_dict(), "controller": cfg["controller"]})
    with atomic_dir(out, force=force, command="qr replay") as tmp:
        figs = report.figures(result, tmp)
        write_text(tmp / "report.md", report.report(doc, figs))
        write_json(tmp / "replay.json", doc)
    if track:
        from .. import tracking
        from ..shipped import vehicle_file

        with tracking.run("replay", track, doc["config"], inputs=[*flights, *map(vehicle_file, vehicles)],
                          description=report.headline(doc)) as r:
            r.metrics(report.metrics(doc))
            r.tags({"qr.models": ",".join(doc["labels"].values()), "qr.controller": controller})
            for p in ("replay.json", "report.md"):
                r.artifact(Path(out) / p)
    say(report.headline(doc))
    return doc
