"""A residual trained through the rollout (``qr learn residual``, docs/spec/hybrid.md), as a library.

``run(flights, measured, infos, vehicle, vehicle_file, settings) -> ResidualTraining`` (:mod:`.training`)
cuts the flights into the evaluate protocol's windows (:func:`qr.pieces.rollout_pieces`), trains the
network (:mod:`qr.residual_fit`) and, where asked, the band's ensemble (:mod:`qr.ensemble`), and scores
the hybrid on the validation windows; :func:`.training.check_flights` refuses what must not train.
``document`` makes training.json of a :class:`ResidualTraining`, ``report`` its report.md and figure
(``sentences``: those the report and the log share), ``logged_model`` the self-contained torch module MLflow
logs.  The stage that reads and writes files is :mod:`qr.stages.learn_residual`.
"""


def __getattr__(name: str):
    # on first use: composing the config tree must not import torch and the plant
    if name in ("run", "ResidualTraining", "Settings", "check_flights"):
        from . import training

        return getattr(training, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
