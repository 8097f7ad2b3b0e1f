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
