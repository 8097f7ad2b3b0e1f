"""The diagnosis library: what the nominal model gets wrong, the cause named, the model extended.

``core`` (prepare the labels, identify, select, bootstrap; the estimates it reads, full and even/odd
halves with matched rotor signals, are the filter stage's: :mod:`qr.estimation.crossfit`), ``noise``,
``replay``, ``slow_torque``,
``remainder``, ``accelerometer``, ``coefficients`` (vehicle-file checks), ``report`` (report.md,
figures, diagnosis.json), ``settings`` (DiagnoseConfig).  These take and return arrays and
dataframes; the stage that reads and writes files is :mod:`qr.stages.diagnose`.
"""
