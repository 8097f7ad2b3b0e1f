"""The diagnosis library: what the nominal model gets wrong, the cause named, the model extended.

``qr.diagnose.run(estimates, flights, vehicle, settings) -> Diagnosis`` (:mod:`.diagnosis`) builds a
diagnosis by named steps: ``labels`` (the residual labels), ``fit`` (selection, delay, parameters,
standard errors), ``held_out`` (what the held-out part supports; whether the model describes the
flights), ``replay`` (replay and rollout), ``remainder`` (structure beyond the catalog, the learned
torque remainder), ``accelerometer``, ``coefficients`` (statements about the vehicle file); ``core`` holds
the algebra they share, ``noise`` the noise floor, ``slow_torque`` the slow torque balance, ``flights``
how it takes its flights (:mod:`qr.intake`), ``settings`` the settings (DiagnoseConfig).  ``document`` makes
diagnosis.json of a :class:`Diagnosis`, ``report`` its report.md and figures (``drawing`` starts them early).
The estimates it reads are the filter stage's (:mod:`qr.estimation.crossfit`), taken by the intake.  These take and return arrays and dataframes; the stage that
reads and writes files is :mod:`qr.stages.diagnose`.
"""


def __getattr__(name: str):
    # ``run`` and ``Diagnosis`` on first use: the config tree imports .settings, and composing it must
    # not import the whole library (numba kernels, the plant)
    if name in ("run", "Diagnosis", "Settings"):
        from . import diagnosis

        return getattr(diagnosis, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
