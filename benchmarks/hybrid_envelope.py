"""Where a fold's rollout-trained hybrid loses its body rate: inside or outside the training envelope.

    .venv/bin/python benchmarks/hybrid_envelope.py results/generalization/payload/trajectory-sideways [RESIDUAL_DIR]

Reads a fold of rule generalization_fold (its training diagnosis's physical vehicle, its residual, the filter
stage's files of its flights) and prints, at h = H, the MAE ratio to rate_frozen (the nominal vehicle, ω held;
torch rollout, windows pooled: close to, not the same as, qr evaluate's per-flight table) of p, v, R, ω on the fold's validation flights (the training side's) and on its scored flights, split
into windows whose start state lies inside / outside the network inputs' training range, for:
the physical model; the hybrid; the hybrid with its torque dropped; the hybrid with each network input clamped
to its training range.  A diagnosis of the hypothesis "the network's torque extrapolates", not a score.
"""

import json
import sys
from pathlib import Path

import numpy as np
import torch

from qr import residual_fit as rf
from qr.config import to_dict
from qr.estimation.settings import resolve as resolve_filter
from qr.flight import read_flight
from qr.frames import quat_to_rot
from qr.residual import features
from qr.rollout import EvaluateConfig, windows
from qr.rollout_torch import DTYPE, ResidualNet, body_features, rollout, window_errors
from qr.plant_state import X_QUAT, X_RATE, X_VEL
from qr.sim.plant import true_params
from qr.pieces import rollout_pieces
from qr.stages.learn_residual import compose
from qr.vehicle import load_vehicle, vehicle_from_dict

torch.set_num_threads(1)
fold = Path(sys.argv[1])
res_dir = Path(sys.argv[2]) if len(sys.argv) > 2 else fold / "residual"
set_name = fold.parent.name
results = fold.parent.parent.parent
doc = json.loads((fold / "fold.json").read_text())
tj = json.loads((res_dir / "training.json").read_text())
val_f = [Path(f).stem for f in tj["flights"]["validation"]]
test_f = [Path(f).stem for f in doc["split"]["test"]]
train_f = [Path(f).stem for f in doc["split"]["train"] if Path(f).stem not in val_f]

plain = to_dict(compose(["learn.keep_remainder=false"]))
ecfg = EvaluateConfig.from_dict(plain["evaluate"])
fcfg = plain["filter"]
resolve_filter(fcfg)
H = ecfg.horizon
raw = load_vehicle(fold / "training_diagnosis" / "extended_vehicle.yaml").to_dict()
raw.pop("torque_remainder", None)
raw.pop("residual", None)
phys = vehicle_from_dict(raw)
hyb = load_vehicle(res_dir / "hybrid_vehicle.yaml")
net = ResidualNet.from_residual(hyb.residual)
P = torch.as_tensor(true_params(phys, phys.effects, residual=False), dtype=DTYPE)
P0 = P.numpy()
# qr evaluate's rate_frozen: the nominal vehicle (the set's diagnosis input), no effects, ω held
Pn0 = true_params(load_vehicle(results / "diagnosis" / set_name / "vehicle.yaml"), residual=False)
Pn = torch.as_tensor(Pn0, dtype=DTYPE)


def batch(names, stride=1):
    pcs = []
    for f in names:
        path = results / "ingest" / set_name / f"{f}.parquet"
        rep = json.loads((results / "filter" / set_name / f"{f}.nis.json").read_text())
        est = results / "filter" / set_name / f"{f}.crossfit.parquet"
        for st, meas, keep in rollout_pieces([str(path)], [read_flight(str(path))], phys, ecfg, fcfg, [rep], [str(est)])[0]:
            w = windows(st, meas, H, ecfg.max_input_gap, keep)
            s = rf.full_starts(w, H)[::stride]
            if len(s):
                pcs.append(rf.Piece(f, w, s, np.zeros(0, int)))
    return rf.gather(pcs, "train", H, P0), pcs


def phi_of(X, U):
    R = quat_to_rot(X[:, X_QUAT] / np.linalg.norm(X[:, X_QUAT], axis=1, keepdims=True))
    v_b = np.einsum("nji,nj->ni", R, X[:, X_VEL])
    return features(net.inputs, v_b, X[:, X_RATE], -R[:, 2, :], U, net.rotor_speed_scale)


class Clamped(torch.nn.Module):
    def __init__(self, net, lo, hi, torque=True):
        super().__init__()
        self.net, self.torque = net, torque
        self.lo, self.hi = torch.as_tensor(lo, dtype=DTYPE), torch.as_tensor(hi, dtype=DTYPE)

    def wrench(self, v_b, w, g_b, u):
        phi = body_features(self.net.inputs, v_b, w, g_b, u, self.net.rotor_speed_scale)
        out = self.net(torch.maximum(torch.minimum(phi, self.hi), self.lo))
        return out if self.torque else torch.cat([out[:, :3], torch.zeros_like(out[:, 3:])], 1)


tb, tpcs = batch(train_f, 4)
# the training envelope: every sample of the training windows (filter's states, rotor speeds acting)
X = np.concatenate([p.windows.X0[p.windows.ok] for p in tpcs])
U = np.concatenate([p.windows.inputs(P0)[p.windows.ok] for p in tpcs])
ph = phi_of(X, U)
lo, hi = ph.min(0), ph.max(0)
inf = np.full_like(lo, np.inf)
models = {"physical": None, "hybrid": net, "hybrid, torque dropped": Clamped(net, -inf, inf, torque=False),
          "hybrid, inputs clamped": Clamped(net, lo, hi)}
names = [n for g in net.inputs for n in {"v_b": ["v_b"] * 3, "omega": ["omega"] * 3, "g_b": ["g_b"] * 3,
                                         "u": ["u"] * 4, "u2": ["u2"] * 4}[g]]
for g in net.inputs:  # one input group clamped at a time: whose extrapolation carries the torque
    m = np.array([n == g for n in names])
    models[f"hybrid, {g} clamped"] = Clamped(net, np.where(m, lo, -inf), np.where(m, hi, inf))


def mae_at_H(E):
    e = E[:, -1, :].numpy()
    return np.nanmean(e, axis=0)


for label, names in (("validation (training side)", val_f), ("scored (held out)", test_f)):
    b, pcs = batch(names)
    Xs = b.X0.numpy()
    inside = np.all((phi_of(Xs, b.U[:, 0].numpy()) >= lo) & (phi_of(Xs, b.U[:, 0].numpy()) <= hi), axis=1)
    with torch.no_grad():
        bn = rf.gather(pcs, "train", H, Pn0)
        ref = window_errors(rollout(bn.X0, bn.U, bn.dt, Pn, None, frozen=True), *bn.truth)
        print(f"\n{label}: {len(b)} windows, {100 * (1 - inside.mean()):.0f} % start outside the inputs' "
              f"training range")
        for name, m in models.items():
            E = window_errors(rollout(b.X0, b.U, b.dt, P, m), *b.truth)
            row = []
            for sel, tag in ((slice(None), "all"), (inside, "in"), (~inside, "out")):
                if isinstance(sel, np.ndarray) and not sel.any():
                    continue
                r = mae_at_H(E[sel]) / mae_at_H(ref[sel])
                row.append(f"{tag} " + "/".join(f"{x:.2f}" for x in r))
            print(f"  {name:26s} " + "   ".join(row))
