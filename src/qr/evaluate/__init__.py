"""The rollout evaluation: vehicle models scored by multi-step open-loop rollout (``qr evaluate``,
docs/spec/evaluate.md).

``qr.evaluate.run(pieces, models, settings, ...) -> Evaluation`` (:mod:`.evaluation`): each model and the
references rolled out from every start of the scored flights' pieces, the windows checked against the
training flights' envelope, the bands.  :mod:`.document` makes evaluation.json of an Evaluation,
:mod:`.report` its report.md and figures.  The stage that reads and writes files is :mod:`qr.stages.evaluate`;
the workflow's held-out protocol is :mod:`qr.stages.evaluate_sets`.
"""


def __getattr__(name: str):
    # on first use: ``python -m qr.evaluate`` must not import the library before the command line is read
    if name in ("run", "Evaluation", "Settings", "Model"):
        from . import evaluation

        return getattr(evaluation, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
