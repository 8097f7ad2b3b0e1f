"""Data for the learning tests: a synthetic drag flight filtered as the workflow filters, and random tables."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pandas as pd

from conftest import VEHICLES

DRAG = "linear_drag:kx=0.3,ky=0.3,kz=0.1"


@lru_cache(maxsize=None)
def drag_flight(seed: int = 1, duration: float = 60.0):
    """``(vehicle, effects, truth, states)``: Hummingbird with linear drag hidden in the plant, 100 Hz,
    the noisy log filtered by ``qr.estimation.estimate`` with the workflow's filter (``filter=auto``)."""
    from qr.config import compose, to_dict
    from qr.effects import parse_effect_spec
    from qr.estimation import estimate
    from qr.sim.synth import SynthConfig, synthesize
    from qr.vehicle import load_vehicle

    vehicle = load_vehicle(VEHICLES / "asctec_hummingbird.yaml")
    effects = [parse_effect_spec(DRAG)]
    flight, truth = synthesize(vehicle, effects, SynthConfig(duration=duration, rate=100.0, seed=seed))
    states, _ = estimate(flight, vehicle, to_dict(compose(["filter=auto"]))["filter"])
    return vehicle, effects, truth, states


def random_table(flights: int = 4, n: int = 400, seed: int = 0, rate: float = 100.0) -> pd.DataFrame:
    """A learning table of random inputs whose f_a is linear in v_b plus noise (tau_a linear in omega)."""
    from qr.datasets import GROUPS, columns, target_columns

    rng = np.random.default_rng(seed)
    parts = []
    for i in range(flights):
        df = pd.DataFrame(rng.normal(size=(n, len(columns(GROUPS)))), columns=columns(GROUPS))
        df.insert(0, "t", np.arange(n) / rate + 3.0 * i)
        df.insert(0, "flight", f"f{i:02d}")
        v = df[columns(["v_b"])].to_numpy()
        w = df[columns(["omega"])].to_numpy()
        df[target_columns("f_a")] = -0.3 * v + 0.05 + 0.01 * rng.normal(size=(n, 3))
        df[target_columns("tau_a")] = 0.002 * w + 1e-4 * rng.normal(size=(n, 3))
        parts.append(df)
    return pd.concat(parts, ignore_index=True)


def residual_wrench(res, phi: np.ndarray) -> np.ndarray:
    """A vehicle file's learned wrench (N, 6) for features ``φ`` (N, d) in NumPy (:func:`qr.residual.forward`:
    scaled inputs, tanh/relu hidden layers, scaled outputs): the reference the compiled plant, its torch
    twin and the logged MLflow model are tested against."""
    from qr.residual import forward

    return forward(res, phi)
