"""Export a vehicle (nominal, extended or hybrid) to the simulators people use (docs/spec/export.md).

One module per simulator (:mod:`.rotorpy`, :mod:`.px4_gz`, :mod:`.mujoco`), each turning the TRUE
plant's parameters (:mod:`.mapping`, the one place for units and for the table of what maps how)
into the simulator's files and the rows of ``mapping.md``.  The stage that writes them is
:mod:`qr.stages.export`; ``python -m qr.export`` = ``qr export``.
"""

TARGETS = ("rotorpy", "px4-gz", "mujoco")
