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


def _makespan(loads: list[int], cores: int) -> float:
    """Equal-cost members dealt into processes (``loads``: members each), the processes sharing ``cores``
    equally, none faster than one core: when the last one ends, in member-times."""
    left, t = sorted(float(x) for x in loads if x), 0.0
    while left:
        speed = min(1.0, cores / len(left))
        dt = left[0] / speed
        t += dt
        left = [x - dt * speed for x in left[1:]]
        left = [x for x in left if x > 1e-12]
    return t


def test_the_default_process_count_is_the_fewest_that_keep_the_cores_busy_to_the_end():
    """learn.member_jobs=0: of all process counts, the members (dealt in turn) end soonest with this one,
    and with no fewer processes; 5 members on 2 cores: 3 processes (2.5 member-times, not 2's 3)."""
    import math

    from qr.ensemble import jobs

    for cores in (1, 2):
        for members in range(1, 13):
            def end(n):
                return _makespan([len(range(j, members, n)) for j in range(n)], cores)

            n = jobs(0, members, math.inf, cores=cores)
            best = min(end(k) for k in range(1, members + 1))
            assert end(n) == best and all(end(k) > best for k in range(1, n)), (cores, members, n)
    assert jobs(0, 5, math.inf, cores=2) == 3 and _makespan([2, 2, 1], 2) == 2.5 and _makespan([3, 2], 2) == 3
    assert jobs(0, 5, 10.0, cores=2) == 1 and jobs(4, 5, 10.0, cores=2) == 4  # quick members serially; a setting wins
