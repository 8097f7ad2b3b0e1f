"""The band's ensemble of ``qr learn residual`` (:mod:`qr.ensemble`, docs/evaluate.md "Bands").

Members start from the trained network (warm start): after one Adam step from it, every weight lies
within the step size ``lr`` of the network's (Adam's first bias-corrected step is ``lr · g / (|g| + ε)``),
and none is still the network's own (the start is never kept).  Members trained in one process or in two
spawned processes are the same bytes, and training them leaves the process's torch random state as the
network alone leaves it.
"""

import json

import numpy as np

from conftest import VEHICLES

LR = 3e-3
# one batch holds every window: exactly one Adam step per epoch
TINY = ["learn.horizon=10", "learn.width=4", "learn.depth=1", "learn.epochs=1", "learn.stride=8", "learn.batch=100000",
        f"learn.lr={LR}", "learn.members=2", "learn.member_epochs=1"]


def _weights(path):
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def test_members_start_from_the_network_and_are_the_same_bytes_in_one_or_two_processes(tmp_path):
    import torch

    from qr.sim.synth import SynthConfig, write_synth
    from qr.stages.learn_residual import run_residual
    from qr.vehicle import load_vehicle

    v = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    for name, seed in (("a", 1), ("b", 2), ("c", 3)):
        write_synth(tmp_path / name, v, [], SynthConfig(duration=6, rate=100, seed=seed))
    fl = [tmp_path / n / "flight.csv" for n in "abc"]
    quiet = lambda m: None  # noqa: E731
    docs, rng = {}, {}
    for tag, extra in (("none", ["learn.members=0"]), ("j1", ["learn.member_jobs=1"]), ("j2", ["learn.member_jobs=2"])):
        docs[tag] = run_residual(fl, tmp_path / "a" / "vehicle.yaml", tmp_path / tag, [*TINY, *extra], track=False,
                                 log=quiet)
        rng[tag] = torch.get_rng_state()
    assert docs["j1"]["ensemble"]["jobs"] == 1 and docs["j2"]["ensemble"]["jobs"] == 2  # really two processes
    assert torch.equal(rng["none"], rng["j1"])  # members draw nothing from the process's random state
    main = (tmp_path / "none" / "residual.npz").read_bytes()
    for tag in ("j1", "j2"):
        assert (tmp_path / tag / "residual.npz").read_bytes() == main
    for k in (1, 2):
        assert ((tmp_path / "j1" / "members" / f"member{k}.npz").read_bytes()
                == (tmp_path / "j2" / "members" / f"member{k}.npz").read_bytes())
    assert ((tmp_path / "j1" / "hybrid_vehicle.bands.json").read_text()
            == (tmp_path / "j2" / "hybrid_vehicle.bands.json").read_text())

    net = _weights(tmp_path / "none" / "residual.npz")
    band = json.loads((tmp_path / "j1" / "hybrid_vehicle.bands.json").read_text())
    for k, m in enumerate(band["members"], 1):
        assert m["epochs_run"] == 1 and m["best_epoch"] == 1  # the start itself is never kept
        w = _weights(tmp_path / "j1" / "members" / f"member{k}.npz")
        assert w.keys() == net.keys()
        moved = max(float(np.abs(w[n] - net[n]).max()) for n in net)
        assert 0 < moved <= LR * (1 + 1e-9)  # one Adam step from the network's weights, not a new network
