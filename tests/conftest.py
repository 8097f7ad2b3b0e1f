import os
import signal
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("QR_DATA", ROOT.parent / "shared" / "data" / "imrclab-crazyflie"))
VEHICLES = ROOT / "conf" / "vehicle"

# Two xdist workers on two cores: one numba thread each, or the compiled rollouts of both workers fight
# over the cores (the rollout's sums do not depend on the thread count: tests/evaluate/test_evaluate.py).
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")

# A test run started in the background (`make test &`, nohup, a non-interactive shell) inherits an
# ignored SIGINT, which Python and every child process keep; the Ctrl-C tests need it delivered.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def _module_fixtures(item) -> list[str]:
    """The module- or session-scoped fixtures of ``item`` defined in its own test module (not in a conftest)."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return []
    own = item.nodeid.split("::")[0]
    return sorted(name for name in info.names_closure for d in info.name2fixturedefs.get(name, ())[-1:]
                  if d.scope in ("module", "package", "session") and d.baseid == own)


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(config, items):
    """Under `--dist loadgroup`: the xdist groups, and the order in which xdist hands out the tests."""
    if not getattr(config.option, "loadgroup", False):  # set on each worker under --dist loadgroup
        return (yield)
    # Before xdist's own hook names the groups: a module's tests that share a module-scoped fixture (a flight
    # flown and diagnosed, a refinement) run on one worker, so that the fixture is computed once instead of once
    # per worker that runs one of them (xdist otherwise hands the tests out one by one).
    for item in items:
        if not item.get_closest_marker("xdist_group") and _module_fixtures(item):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))
    result = yield
    # The longest first (xdist hands out the groups, largest first, then single tests in this order): the tests
    # marked slow start at once, so that the two workers end together instead of one finishing them alone.
    items.sort(key=lambda i: i.get_closest_marker("slow") is None)
    # The workflow tests share one reduced run per xdist group; if `--dist loadgroup` stops grouping (pytest 9.2
    # with xdist 3.8 did), every worker would run it again: refuse rather than pay twice.
    ungrouped = [i.nodeid for i in items if i.get_closest_marker("xdist_group") and "@" not in i.nodeid]
    if ungrouped:
        raise pytest.UsageError(f"--dist loadgroup did not group {ungrouped[0]} (pytest/pytest-xdist "
                                "versions); install from environment.lock")
    return result


@pytest.fixture(autouse=True)
def _isolated(tmp_path, monkeypatch):
    """Every test gets its own results dir; MLflow off unless a test turns it on."""
    monkeypatch.setenv("QR_RESULTS", str(tmp_path / "results"))
    monkeypatch.setenv("QR_TRACKING", "off")
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)


@pytest.fixture
def hummingbird():
    from qr.vehicle import load_vehicle

    return load_vehicle(VEHICLES / "asctec_hummingbird.yaml")


@pytest.fixture
def crazyflie():
    from qr.vehicle import load_vehicle

    return load_vehicle(VEHICLES / "crazyflie21_brushless.yaml")


def signals_from_truth(truth):
    from qr.states import signals

    return signals(truth)


def run_cli(args, capsys):
    """Run ``qr ARGS`` in-process; returns (status, stdout, stderr)."""
    from qr.cli import main

    status = main([str(a) for a in args])
    out = capsys.readouterr()
    return status, out.out, out.err


def rng(seed=0):
    return np.random.default_rng(seed)


def small_flight(n=200, seed=0, yaw_amplitude=0.5):
    """A legal canonical flight of ``n`` samples at 100 Hz (the Hummingbird's hover rotor speed)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    yaw = yaw_amplitude * np.sin(t)
    df = pd.DataFrame({"t": t, "px": np.sin(t), "py": np.cos(t), "pz": 1 + 0.1 * t,
                       "qw": np.cos(yaw / 2), "qx": 0.0, "qy": 0.0, "qz": np.sin(yaw / 2)})
    for i in range(1, 5):
        df[f"u{i}"] = 5872.0 + rng.normal(0, 20, n)
    return df


def ground_rows(n, p, u, t0, seed=0, rate=100.0):
    """``n`` samples of a vehicle at rest at ``p`` (level; mocap noise 0.5 mm and 0.17 deg), rotor speeds ``u``
    (array or scalar)."""
    rng = np.random.default_rng(seed)
    df = pd.DataFrame({"t": t0 + np.arange(n) / rate})
    for k, c in enumerate(["px", "py", "pz"]):
        df[c] = p[k] + rng.normal(0, 0.0005, n)
    half = rng.normal(0, 0.003 / 2, (n, 3))  # small rotation vectors / 2: a unit quaternion near identity
    q = np.column_stack([np.ones(n), half])
    df[["qw", "qx", "qy", "qz"]] = q / np.linalg.norm(q, axis=1, keepdims=True)
    for c in ["u1", "u2", "u3", "u4"]:
        df[c] = u
    return df


def on_the_ground(flight, vehicle, before_s=5.0, after_s=5.0, spin_up_s=0.0, rate=100.0):
    """``flight`` with ground rows before (motors off, then a spin-up to 0.9 m g on the floor) and after (idle)."""
    p0 = flight[["px", "py", "pz"]].iloc[0].to_numpy() * [1, 1, 0] + [0, 0, 0.05]
    p1 = flight[["px", "py", "pz"]].iloc[-1].to_numpy() * [1, 1, 0] + [0, 0, 0.05]
    n_up = int(spin_up_s * rate)
    off = ground_rows(int(before_s * rate) - n_up, p0, 0.0, 0.0, 0, rate)
    up = ground_rows(n_up, p0, np.sqrt(0.9) * vehicle.hover_speed * np.linspace(0.2, 1, n_up), off["t"].iloc[-1] + 1 / rate, 1, rate)
    air = flight.assign(t=(flight["t"] - flight["t"].iloc[0] + before_s).round(6))
    idle = ground_rows(int(after_s * rate), p1, 0.2 * vehicle.hover_speed, air["t"].iloc[-1] + 1 / rate, 2, rate)
    return pd.concat([off, up, air, idle], ignore_index=True), (before_s, float(air["t"].iloc[-1]))


def run_with_overrides(flight, vehicle_file, out, nis_out, overrides=(), name=None, track=True, crossfit_out=None):
    """The filter stage from Python with Hydra overrides (``['filter=auto']``)."""
    from qr.config import compose, to_dict
    from qr.stages.filter import run_filter

    return run_filter(flight, vehicle_file, out, nis_out, to_dict(compose(list(overrides)))["filter"], name,
                      track=track, crossfit_out=crossfit_out)
