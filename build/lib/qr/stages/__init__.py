"""The stages, one module each: the only layer that reads and writes files and tracks MLflow runs.

``ingest`` (raw log -> canonical flight), ``filter`` (state estimates, cross-fit halves, matched rotor
signals), ``learn`` (residual models, sweeps), ``diagnose`` (named effects, extended vehicle),
``simulate`` (the closed-loop study, stability), ``evaluate`` (multi-step rollout).  Each is
``qr <stage>`` (and ``python -m qr.<stage>``), has a config group in ``conf/``, a rule file in
``workflow/rules/``, a test folder ``tests/stages/`` and a page in ``docs/``.  The libraries under
them take and return arrays and data frames.
"""
