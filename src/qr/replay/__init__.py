"""The closed-loop replay: each vehicle file flown under the vehicle's own controller along the rebuilt
setpoints, against the logged flight (``qr replay``, docs/spec/replay.md).

``qr.replay.run(logs, vehicles, ...) -> Replay`` (:mod:`.replay`) by named steps: ``setup`` (setpoints:
:mod:`.setpoints` and :mod:`.alignment`; the mixer and motor map: :mod:`.mixer`), ``fly`` (:mod:`.fly`:
the controller, :mod:`.controller` (the interface) and :mod:`.lee` (the Crazyflie firmware's Lee
controller), the plant), ``compare`` (:mod:`.compare`).  :mod:`.logs` reads a flight for it, :mod:`.settings`
holds its settings, :mod:`.document` makes replay.json of a Replay, :mod:`.report` its report.md and figures;
:mod:`.rotorpy_controller` flies RotorPy's SE3 controller through the interface.  The stage that reads and
writes files is :mod:`qr.stages.replay`.
"""


def __getattr__(name: str):
    if name in ("run", "Replay"):
        from . import replay

        return getattr(replay, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
