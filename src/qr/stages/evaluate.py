"""``qr evaluate``: score vehicle models by multi-step open-loop rollout (docs/spec/evaluate.md).

Reads the flights and vehicles, takes each flight's pieces (:func:`rollout_pieces`),
runs :func:`qr.evaluate.run`, writes ``OUTDIR/evaluation.json``, ``report.md`` and ``figures/`` all at once
(checked first, built in a temporary folder) and tracks the run (experiment ``qr-evaluate``).  The
workflow's held-out protocol: :mod:`qr.stages.evaluate_sets`.
"""

from __future__ import annotations

import sys

from ..pieces import rollout_pieces

OUTPUTS = ("evaluation.json", "report.md", "figures/")


def run_evaluation(flights, vehicles, out, overrides=(), force: bool = False, log=None,
                   figures: bool = True, reports: list | None = None, track: str | None = None,
                   estimates: list | None = None, labels: list[str] | None = None, trained_on: dict | None = None,
                   split=None, loaded: list | None = None, memo=None) -> dict:
    """Evaluate ``vehicles`` on ``flights``; write ``out`` (checked before any work); the document.

    ``labels``: each model's name in the report (default: its key, the file's name).  ``reports`` /
    ``estimates``: per flight, the filter stage's report (its tuned noise values reused) and cross-fit file
    (a segment's estimate read from it where it matches).  ``trained_on``: the flights the models were
    trained on (``{"flights", "reports", "estimates"}``; default ``evaluate.trained_on``): every window is
    checked against their envelope.  ``split``: the held-out protocol's :class:`qr.holdout.Assignment`
    (without it, a trajectory or speed ``evaluate.split`` selects the flights to score:
    :func:`qr.evaluate.evaluation.sides`).  ``loaded``: the vehicles of ``vehicles``, already in memory;
    ``memo``: what an earlier command of this process took (:class:`qr.intake.Memo`)."""
    from ..outputs import check_out_dir

    t = trained_on or {}
    out = check_out_dir(out, inputs=[*flights, *vehicles, *map(str, t.get("flights", []))], force=force,
                        expected=OUTPUTS)
    from ..evaluate.evaluation import given, model_names
    from ..intake import read_flights
    from ..vehicle import load_vehicle

    # the inputs first: a file that is missing or wrong is refused before the heavy imports and Hydra
    names = model_names([str(v) for v in vehicles])
    vehs = loaded or [load_vehicle(v) for v in vehicles]
    scored = given(flights, reports, estimates, read_flights(flights, memo))
    from ..atomic import atomic_dir, write_json
    from ..config import compose_stage
    from ..evaluate import document, report
    from ..evaluate.evaluation import Model, Settings, run, sides

    say = log or (lambda msg: print(f"qr evaluate: {msg}", file=sys.stderr))
    s = Settings.of(compose_stage(overrides, "evaluate", "evaluate.horizon=100"))
    scored, trained, split = sides(scored, given(t["flights"], t.get("reports"), t.get("estimates")) if t else None,
                                   split, s.evaluate, say)
    both = [*scored, *(trained or ())]  # taken at once: every flight checked before any is filtered
    cut = rollout_pieces([g.path for g in both], [read_flights([g.path], memo)[0] if g.measured is None else g.measured
                                                   for g in both], vehs[0], s.evaluate, s.filter,
                         [g.report for g in both], [g.estimates for g in both], say, vehicles[0], memo)
    train = [p for ps in cut[len(scored):] for p in ps] if trained else None
    result = run(list(zip([g.path for g in scored], cut)), [Model(k, str(v), lab, veh) for k, v, lab, veh in
                                                            zip(names, vehicles, labels or names, vehs)],
                 s, train, [g.path for g in trained] if trained else None, split, say)
    doc = document.document(result)
    with atomic_dir(out, force=force, command="qr evaluate") as tmp:
        report.write(tmp, result, figures)
        write_json(tmp / "evaluation.json", doc)
    if track:  # one MLflow run (experiment qr-evaluate), the report's first sentence as its description
        from .. import tracking
        from ..shipped import vehicle_file

        with tracking.run("evaluate", track, doc["config"], inputs=[*(g.path for g in scored),
                          *map(vehicle_file, vehicles)], description=report.headline(doc)) as r:
            r.metrics(report.metrics(doc))
            r.tags({"qr.models": ",".join(report.metric_names(doc).values())})
            for p in ("evaluation.json", "report.md"):
                r.artifact(out / p)
    say(f"wrote {out}/evaluation.json")
    return doc


