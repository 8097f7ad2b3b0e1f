"""Export a vehicle (nominal, extended or hybrid) to the simulators people use (docs/spec/export.md).

``qr.export.run(vehicle, vehicle_path, to, version) -> Export`` (:mod:`.export`) builds every file in
memory: one module per simulator (:mod:`.rotorpy`, :mod:`.px4_gz`, :mod:`.mujoco`) turns the TRUE
plant's parameters (:mod:`.mapping`, the one place for units and for the table of what maps how) into
the simulator's files and the rows of ``mapping.md``, which :mod:`.document` writes of the result.
The stage that writes them is :mod:`qr.stages.export`; ``python -m qr.export`` = ``qr export``.
"""


def __getattr__(name: str):
    if name in ("run", "Export"):
        from . import export

        return getattr(export, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
