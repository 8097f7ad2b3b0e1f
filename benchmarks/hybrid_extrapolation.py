"""A residual trained on slow synthetic flights and scored on a fast one: how the learned torque extrapolates.

    .venv/bin/python benchmarks/hybrid_extrapolation.py DIR [damp|flap|damp+flap] [HYDRA_OVERRIDES...]
    C=0.04 .venv/bin/python benchmarks/hybrid_extrapolation.py /tmp/x damp learn.activation=relu

The truth (a Hummingbird) carries a torque the nominal vehicle lacks, growing with a state, hidden through the
TRUE plant's torque remainder: ``damp`` a rate damping tau = -C omega on roll and pitch (C from the environment,
N m s, default 0.01), ``flap`` a torque 0.004 N m per m/s of body velocity.  ``qr synth`` flies two slow 30 s
flights (v_max 0.7 m/s, tilt 8 deg; they train, the second validates) and a fast 20 s one (2 m/s, 25 deg; scored)
into DIR (made once, reused), ``qr learn residual`` trains (H = 20, or the environment's H; the given overrides) into DIR/res_<overrides>
(reused if there), and the compiled rollout scores the fast flight's windows inside / outside the training
envelope (qr.envelope): MAE ratio to rate_frozen at h = H of p, v, R, omega for the nominal vehicle, the hybrid
and the truth (docs/learn.md, "Beyond the training envelope").
"""

import json
import os
import sys
from pathlib import Path

import numpy as np

from qr.sim.synth import SynthConfig, write_synth
from qr.sim.trajectory import TrajectoryConfig
from qr.vehicle import load_vehicle, save_vehicle

tmp = Path(sys.argv[1])
mech = sys.argv[2] if len(sys.argv) > 2 else "damp"
extra = sys.argv[3:]
H = int(os.environ.get("H", "20"))  # the horizon of training and scoring
veh = Path(__file__).resolve().parent.parent / "conf" / "vehicle" / "asctec_hummingbird.yaml"
tmp.mkdir(exist_ok=True)
if not (tmp / "fast").exists():
    W = np.zeros((3, 11))
    if "damp" in mech:
        W[0, 3] = W[1, 4] = -float(os.environ.get("C", "0.01"))
    if "flap" in mech:
        W[0, 1], W[1, 0] = 0.004, -0.004
    true = load_vehicle(veh).with_changes(torque_remainder={"weights": W.tolist()})
    slow = TrajectoryConfig(v_max=0.7, tilt_max_deg=8)
    fast = TrajectoryConfig(v_max=2.0, tilt_max_deg=25)
    for name, seed, dur, tc in (("a", 1, 30, slow), ("b", 2, 30, slow), ("fast", 3, 20, fast)):
        write_synth(tmp / name, true, [], SynthConfig(duration=dur, rate=100, seed=seed, trajectory=tc))
    save_vehicle(true, tmp / "true.yaml")
from qr.stages.learn_residual import run_residual
tag = "_".join(extra).replace("=", "").replace(".", "")[:60] or "default"
out = tmp / f"res_{tag}"
doc = json.loads((out / "training.json").read_text()) if (out / "training.json").exists() else run_residual([tmp / "a" / "flight.csv", tmp / "b" / "flight.csv"], tmp / "a" / "vehicle.yaml", out,
                   [f"learn.horizon={H}", "learn.stride=3", "learn.members=0", *extra], track=False, log=lambda m: None, force=True)
# score with the compiled rollout, windows split by the training envelope
from qr.config import to_dict
from qr.estimation.settings import resolve as resolve_filter
from qr.flight import read_flight
from qr.rollout import EvaluateConfig, windows, score_plant, summary, pool, at, MODEL, RATE_FROZEN
from qr.envelope import Envelope
from qr.sim.plant import true_params
from qr.pieces import rollout_pieces
from qr.stages.learn_residual import compose

plain = to_dict(compose([f"learn.horizon={H}", f"evaluate.horizon={H}"]))
ecfg = EvaluateConfig.from_dict(plain["evaluate"]); fcfg = plain["filter"]; resolve_filter(fcfg)
nom = load_vehicle(tmp / "a" / "vehicle.yaml")
def wins(name):
    f = tmp / name / "flight.csv"
    return [windows(st, meas, H, ecfg.max_input_gap, keep) for st, meas, keep in
            rollout_pieces([str(f)], [read_flight(str(f))], nom, ecfg, fcfg)[0]]
env = Envelope.of(wins("a") + wins("b"), H)
fast = wins("fast")
models = {"rate_frozen": (true_params(nom, residual=False), RATE_FROZEN)}
for k, p in (("nominal", tmp / "a" / "vehicle.yaml"), ("hybrid", out / "hybrid_vehicle.yaml"), ("truth", tmp / "true.yaml")):
    v = load_vehicle(p); models[k] = (true_params(v, v.effects), MODEL)
res = {}
for tag in ("all", "in", "out"):
    parts = []
    for w in fast:
        o = env.outside(w, H)["any"]
        idx = np.flatnonzero(w.ok)
        sel = idx if tag == "all" else idx[~o] if tag == "in" else idx[o]
        if len(sel):
            wk = w.scored_at(sel)
            parts.append({k: score_plant(wk, H, P, mode) for k, (P, mode) in models.items()})
    b = {k: summary(*v) for k, v in pool(parts).items()}
    n = int(sum(len(np.flatnonzero(w.ok)) for w in fast))
    res[tag] = {k: [round(at(b[k], H, q) / at(b["rate_frozen"], H, q), 3) for q in ("p", "v", "R", "w")] for k in b if k != "rate_frozen"}
print(f"{mech}, {' '.join(extra) or 'defaults'}: best epoch {doc['epochs']['best']}, best validation loss "
      f"{min([doc['initial_loss']['val_loss']] + [e['val_loss'] for e in doc['loss_per_epoch']]):.3f}")
for tag, r in res.items():
    for k, v in r.items():
        print(f"  fast flight, windows {tag}: {k:8s} p / v / R / w " + " / ".join(f"{x:.3f}" for x in v))
