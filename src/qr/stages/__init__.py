"""The stages, one module each: read the inputs, call one library ``run``, write one folder through
:mod:`qr.atomic`, track the MLflow run (the only layer that tracks); at most 60 lines of code each.

``ingest`` (raw log -> canonical flight), ``filter`` (state estimates, cross-fit halves, matched rotor
signals), ``learn`` (residual models, sweeps; ``learn_residual``: a residual trained through the rollout),
``diagnose`` (named effects, extended vehicle), ``simulate`` (the closed-loop study, stability), ``evaluate``
(multi-step rollout), ``replay`` (closed loop under the vehicle's controller), ``export`` (a simulator's
files).  Each is ``qr <stage>`` (and ``python -m qr.<stage>``), has a config group in ``conf/``, a rule file
in ``workflow/rules/``, a test folder ``tests/<stage>/`` and a page in ``docs/``.  The workflow's per-set glue
lives beside its stage in ``<stage>_sets.py``; ``sweep_callback`` is the Hydra sweeps' base.
"""
