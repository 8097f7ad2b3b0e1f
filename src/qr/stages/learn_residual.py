"""Stage learn, ``qr learn residual``: a residual trained through the rollout (docs/spec/hybrid.md).

    qr learn residual FLIGHT.csv [FLIGHT2.csv ...] --vehicle VEHICLE.yaml --out OUTDIR [HYDRA_OVERRIDES...]
    qr learn residual a.csv b.csv c.csv --vehicle v.yaml --out sweep -m learn.width=16,32 learn.depth=1,2

The file I/O and MLflow layer around :mod:`qr.residual_fit`: the flights' windows (split and
filtered by the one path ``qr evaluate`` uses, :func:`qr.stages.evaluate.estimated_pieces`), the
training, then ``OUTDIR/hybrid_vehicle.yaml`` (the vehicle plus the key ``residual``),
``residual.npz`` (the weights, :mod:`qr.residual`), ``training.json`` (schema ``qr.residual/1``),
``report.md`` and ``figures/training_curve.png``, all written at once after the folder was checked.
An MLflow run in experiment ``qr-learn`` logs the settings, the loss per epoch, the validation MAE per
step h (metric steps) and the model (``mlflow.pytorch``, with its signature).

A sweep (``-m``) runs one job per setting into ``OUTDIR/job<N>/`` and collects them into
``OUTDIR/sweep.csv``; its MLflow runs are children of one parent run (:class:`ResidualSweep`).
Settings are chosen on the validation windows only: no other flight is read.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from ..errors import QrInputError
from .sweep_callback import SweepCallback

OUTPUTS = ("hybrid_vehicle.yaml", "residual.npz", "training.json", "report.md", "figures/",
           "hybrid_vehicle.bands.json", "members/")
SCHEMA = "qr.residual/1"
JOB = "learn_residual"  # Hydra's job name for this stage's multiruns (the task's module)
SWEEP_CSV = "sweep.csv"
PARENT_FILE = ".mlflow_parent"


def compose(overrides=()):
    """The tree with ``learn=residual`` (``learn.*``: :class:`qr.residual_fit.ResidualNode`)."""
    from ..config import compose_stage

    return compose_stage(["learn=residual", *overrides], "evaluate", "learn.width=16")


def run_residual(flights, vehicle, out, overrides=(), force: bool = False, log=None, cfg=None,
                 reports: list | None = None, estimates: list | None = None, track: bool = True,
                 run_name: str = "residual", parent_id: str | None = None, split=None) -> dict:
    """Train on ``flights`` on top of ``vehicle``; write ``out`` (checked before any work); the
    training.json document.  ``cfg``: the composed tree (else composed from ``overrides``);
    ``reports`` / ``estimates``: the filter stage's files of each flight (as :func:`qr.stages.evaluate.
    run_evaluation` takes them).  ``split``: a :class:`qr.holdout.SplitConfig` instead of the tree's
    ``evaluate.split``: the validation flights are drawn by it (:func:`qr.holdout.validation`), and a
    flight it scores is refused."""
    from ..outputs import check_out_dir

    flights = [str(f) for f in flights]
    out = check_out_dir(out, inputs=[*flights, vehicle], force=force, expected=OUTPUTS)
    from dataclasses import asdict, replace

    from .. import holdout
    from .. import residual_fit as rf
    from ..config import to_dict
    from ..estimation.settings import resolve as resolve_filter
    from ..flight import read_flight
    from ..rollout import EvaluateConfig, windows
    from ..vehicle import load_vehicle, vehicle_from_dict
    from .evaluate import estimated_pieces

    say = log or (lambda msg: print(f"qr learn residual: {msg}", file=sys.stderr))
    cfg = compose(overrides) if cfg is None else cfg
    plain = to_dict(cfg)
    rcfg = rf.ResidualConfig.from_dict(plain["learn"])
    ecfg = EvaluateConfig.from_dict(plain["evaluate"])
    filter_cfg = plain["filter"]
    resolve_filter(filter_cfg)
    seed = int(plain.get("seed", 0))
    if len(set(flights)) < len(flights):
        dup = next(f for f in flights if flights.count(f) > 1)
        raise QrInputError(dup, "the same flight is given twice", "give each flight once")
    if split is not None:
        ecfg = replace(ecfg, split=split)
        plain["evaluate"]["split"] = asdict(split)  # training.json says the split it was trained under
    # what the flights fly (evaluate.split: trajectory or speed); a flight the split scores never trains
    infos = ecfg.split.infos(flights)
    scored = [f for f in flights if infos and holdout.named(infos[f], ecfg.split)]
    if scored:
        raise QrInputError(scored[0], f"evaluate.split scores this flight ({infos[scored[0]].describe()}): "
                           "training on it would score a trained flight", "leave it out of the training flights")
    veh = load_vehicle(vehicle)
    if not rcfg.keep_remainder and "torque_remainder" in veh.raw:
        raw = veh.to_dict()
        raw.pop("torque_remainder")
        veh = vehicle_from_dict(raw, vehicle)
    t0 = time.perf_counter()
    pieces = []
    for i, f in enumerate(flights):
        for st, meas, keep in estimated_pieces(f, read_flight(f), veh, ecfg, filter_cfg,
                                               reports[i] if reports else None,
                                               estimates[i] if estimates and reports else None, say):
            pieces.append((f, windows(st, meas, rcfg.horizon, ecfg.max_input_gap, keep)))
    estimate_s = time.perf_counter() - t0
    _, val, by = holdout.validation(flights, ecfg.split, rcfg.validation, infos)
    parts, split = rf.split(pieces, rcfg.horizon, rcfg.validation, rcfg.stride, val, by)
    say(split_sentence(split))
    curve = []
    trained = rf.train(rcfg, veh, parts, seed, say, on_epoch=curve.append)
    if trained.best_epoch == 0:
        say(kept_sentence(trained.initial["val_loss"], [e["val_loss"] for e in trained.epochs],
                          getattr(veh, "residual", None) is not None))
    raw = veh.to_dict()
    raw.pop("residual", None)
    physical = vehicle_from_dict(raw)  # the vehicle without a residual (a fine-tuned one is replaced)
    res = trained.net.to_residual()
    hybrid = physical.with_changes()
    hybrid.residual = res
    blocks = rf.validation_blocks(parts, {"vehicle": physical, "hybrid": hybrid}, rcfg.horizon)
    doc = _document(flights, vehicle, plain, rcfg, seed, split, trained, blocks, estimate_s, veh)
    doc["residual_size"] = training_size(res, parts, rcfg.horizon, physical)
    members = None
    if rcfg.members:
        from .. import ensemble

        t1 = time.perf_counter()
        members, jobs = ensemble.train_members(rcfg, hybrid, parts, split["training"], seed, rcfg.members, say,
                                               trained.wall_s / max(len(trained.epochs), 1))
        scale, where = ensemble.calibrated(physical, hybrid, members, parts, ecfg.horizon)
        members = (members, scale, where)
        doc["ensemble"] = {"members": rcfg.members, "file": ensemble.BANDS_FILE, "scale": scale,
                           "scale_horizon": ecfg.horizon,
                           "calibrated_on": where, "wall_s": time.perf_counter() - t1,
                           "start": ensemble.START, "member_epochs": rcfg.member_epochs,
                           "patience": rcfg.patience, "jobs": jobs,
                           "epochs_run": [m.epochs_run for m in members[0]],
                           "best_epochs": [m.best_epoch for m in members[0]],
                           "resampled": "by flight" if split["by"] != "time" else
                           "not resampled: one flight (members differ by their seeds)"}
    _write(out, force, physical, res, doc, say, members)
    if track:
        _track(run_name, parent_id, doc, out, trained.net, [*flights, vehicle])
    say(f"wrote {out}/hybrid_vehicle.yaml ({trained.wall_s:.0f} s of training, best epoch {trained.best_epoch})")
    return doc


def train_held_out(flights, vehicle, out, overrides=(), reports: list | None = None,
                   estimates: list | None = None, split=None, **kwargs) -> dict:
    """The held-out protocol's training (the workflow's): the flights ``split`` scores (a
    :class:`qr.holdout.SplitConfig`; default the tree's ``evaluate.split``, itself default ``repeat``:
    every third flight) are held out as ``qr evaluate``'s held-out protocol holds them out
    (:func:`qr.stages.evaluate.held_out`) and never opened; the others train, their validation flights drawn
    by the same split (``reports`` / ``estimates``: the filter stage's files, or reports already read, of
    every flight in the same order)."""
    import json

    from .evaluate import held_out

    flights = [str(f) for f in flights]
    if split is None:
        from ..config import to_dict
        from ..rollout import EvaluateConfig

        split = EvaluateConfig.from_dict(to_dict(compose(overrides).evaluate)).split
    train = list(held_out(flights, split).train)
    pick = lambda files: [files[flights.index(f)] for f in train] if files else None  # noqa: E731
    reports = [json.loads(Path(r).read_text()) if isinstance(r, (str, Path)) else r for r in pick(reports) or []]
    return run_residual(train, vehicle, out, overrides, reports=reports or None, estimates=pick(estimates),
                        split=split, **kwargs)


def carry_residual(extended_vehicle, hybrid_vehicle, out) -> None:
    """``out/hybrid_vehicle.yaml``: the physical part of ``extended_vehicle`` (its learned torque remainder
    dropped) carrying the network of ``hybrid_vehicle`` (a ``qr learn residual`` output), trained elsewhere:
    the workflow's chain flies the first set's network on the carry-to set's own model, and fine-tunes it."""
    import shutil

    from ..atomic import atomic_dir
    from ..vehicle import load_vehicle, save_vehicle

    raw = load_vehicle(extended_vehicle).to_dict()
    raw.pop("torque_remainder", None)
    res = load_vehicle(hybrid_vehicle)
    model = Path(hybrid_vehicle).parent / res.raw["residual"]["model"]
    # the network copied beside the file: a path to another folder, written from the temporary folder,
    # would be one level off when the output folder already exists (atomic_dir builds inside it then)
    raw["residual"] = {**res.raw["residual"], "model": model.name}
    with atomic_dir(out, command="qr learn residual (carried)") as tmp:
        shutil.copyfile(model, tmp / model.name)
        save_vehicle(raw, tmp / "hybrid_vehicle.yaml",
                     header=f"{extended_vehicle} (physical part) with the network of {hybrid_vehicle}, carried over")
        load_vehicle(tmp / "hybrid_vehicle.yaml")


def training_size(res, parts, H: int, vehicle) -> dict:
    """The trained wrench's RMS over every sample of the training windows (:func:`qr.residual.rms_size`): the
    size ``qr export`` states where a simulator has no place for the network.  States are the filter's
    estimates moved from the tracked point to the CG; rotor speeds those acting there (delay applied)."""
    from .. import residual as rs
    from ..frames import quat_to_rot, to_body
    from ..plant_state import P_MARKER
    from ..sim.plant import cg_from_tracked, true_params

    P = true_params(vehicle, vehicle.effects, residual=False)
    r = P[P_MARKER].copy()
    X, U, flights = [], [], []
    for pc in parts:
        if not len(pc.train):
            continue
        w = pc.windows
        edge = np.zeros(len(w.t) + 1, int)  # samples s … s + H of each training window
        np.add.at(edge, pc.train, 1)
        np.add.at(edge, np.minimum(pc.train + H + 1, len(w.t)), -1)
        take = np.cumsum(edge[:-1]) > 0
        x = w.X0[take].copy()
        for row in x:
            cg_from_tracked(row, r)
        X.append(x)
        U.append(w.inputs(P)[take])
        flights += [pc.flight] if pc.flight not in flights else []
    X = np.concatenate(X) if X else np.zeros((0, 13))
    U = np.concatenate(U) if U else np.zeros((0, 4))
    R = quat_to_rot(X[:, 6:10]) if len(X) else np.zeros((0, 3, 3))
    return rs.rms_size(res, to_body(R, X[:, 3:6]), X[:, 10:13], R[:, 2, :] * -1.0, U, flights)


def _document(flights, vehicle, plain, rcfg, seed, split, trained, blocks, estimate_s, veh) -> dict:
    import torch

    from ..rollout import QUANTITIES, at

    H = rcfg.horizon
    hs = sorted({h for h in (1, 10, H) if h <= H})
    mae = {m: {q: {str(h): at(b, h, q) for h in hs} for q in QUANTITIES} for m, b in blocks.items()}
    ratio = {m: {q: (None if at(b, H, q) is None or not at(blocks["rate_frozen"], H, q)
                     else at(b, H, q) / at(blocks["rate_frozen"], H, q)) for q in QUANTITIES}
             for m, b in blocks.items()}
    learn = {k: v for k, v in plain["learn"].items() if k not in ("flights", "vehicle", "out", "force")}
    return {
        "schema": SCHEMA,
        "vehicle": str(vehicle),
        "flights": {"training": [f for f in flights if f in split["training"]],
                    "validation": [f for f in flights if f in split["validation"]],
                    "validation_by": split["by"],
                    **({"validation_from_s": split["validation_from_s"]} if split["by"] == "time" else {})},
        "windows": {"training": trained.windows["train"], "validation": trained.windows["val"],
                    "stride": rcfg.stride},
        "horizon": H,
        "loss": {"signal_weights": dict(zip(QUANTITIES, rcfg.signal_weights.vector().tolist())),
                 "horizon_power": rcfg.horizon_power, "horizon_weights": rcfg.horizon_weights().tolist(),
                 "reference": trained.reference,
                 "formula": "sum_s lambda_s sum_h w_h MAE_{s,h} / ref_s; ref_s = rate_frozen's mean MAE over h "
                            "on the training windows"},
        "network": {"inputs": list(trained.net.inputs), "layers": trained.net.to_residual().layers,
                    "activation": trained.net.activation, "start": "fine-tuned from the vehicle's residual"
                    if getattr(veh, "residual", None) is not None else "new, zero output"},
        "epochs": {"run": len(trained.epochs), "best": trained.best_epoch, "stopped": trained.stopped,
                   "limit": rcfg.epochs, "patience": rcfg.patience, "skipped_steps": trained.skipped_steps},
        "seed": seed,
        "wall_s": {"training": trained.wall_s, "estimates": estimate_s},
        "initial_loss": trained.initial,
        "loss_per_epoch": trained.epochs,
        "validation": {"mae": mae, "ratio_to_rate_frozen_at_H": ratio,
                       "models": {"vehicle": "the vehicle without the residual", "hybrid": "with the residual",
                                  "rate_frozen": "the benchmark's physics baseline (qr evaluate's reference)"}},
        "config": {"learn": learn, "evaluate": plain["evaluate"], "filter": plain["filter"]},
        "software": {"torch": torch.__version__, "threads": 1},
    }


def _write(out: Path, force: bool, physical, res, doc: dict, say, members=None) -> None:
    from .. import residual as rs
    from ..atomic import atomic_dir, write_json, write_text
    from ..vehicle import load_vehicle, save_vehicle

    note = (f"trained through the {doc['horizon']}-step rollout on {', '.join(doc['flights']['training'])} "
            "by qr learn residual: a learned wrench, not a physical effect")
    with atomic_dir(out, force=force, command="qr learn residual") as tmp:
        rs.save_weights(res, tmp / "residual.npz")
        raw = physical.to_dict()
        raw["residual"] = rs.block(res, str((tmp / "residual.npz").resolve()), note, doc.get("residual_size"))
        header = (f"Hybrid vehicle from qr learn residual on {', '.join(doc['flights']['training'])}"
                  f": {doc['vehicle']} plus a learned wrench (residual.npz)")
        save_vehicle(raw, tmp / "hybrid_vehicle.yaml", header=header)
        load_vehicle(tmp / "hybrid_vehicle.yaml")  # what was written loads (weights, shapes, scaling)
        if members is not None:
            from .. import ensemble

            ensemble.write(tmp, *members, note, doc["ensemble"]["scale_horizon"])
        (tmp / "figures").mkdir()
        curve_figure(doc, tmp / "figures" / "training_curve.png")
        write_text(tmp / "report.md", report(doc))
        write_json(tmp / "training.json", doc)


def curve_figure(doc: dict, path: Path) -> None:
    from ..report import figures

    ep = doc["loss_per_epoch"]
    fig, ax = figures.subplots(1, 1, figsize=(5.5, 3.4), layout="constrained")
    x = [0] + [e["epoch"] for e in ep]
    ax.plot(x, [doc["initial_loss"]["train_loss"]] + [e["train_loss"] for e in ep], label="training", color="C0")
    ax.plot(x, [doc["initial_loss"]["val_loss"]] + [e["val_loss"] for e in ep], label="validation", color="C1")
    ax.axvline(doc["epochs"]["best"], color="0.5", ls=":", label=f"kept (epoch {doc['epochs']['best']})")
    ax.set_xlabel("epoch (count; 0: " + ("the vehicle's own residual)" if doc["network"]["start"].startswith("fine")
                                        else "the vehicle without the residual)"))
    ax.set_ylabel("rollout loss (ratio: weighted MAE / rate_frozen's)")
    ax.legend(fontsize=7)
    figures.save(fig, path)


def _listed(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def split_sentence(split: dict) -> str:
    """Which flights train and which stop the training (``split``: :func:`qr.residual_fit.split`'s), by path."""
    if split["by"] == "time":
        return (f"1 flight given, {_listed(split['training'])}: its windows ending before t = "
                f"{split['validation_from_s']:.2f} s train, those from t = {split['validation_from_s']:.2f} s on "
                "validate (early stopping; never trained on)")
    n = len(split["training"]) + len(split["validation"])
    return (f"{n} flights given: {len(split['training'])} train{'s' if len(split['training']) == 1 else ''} "
            f"({_listed(split['training'])}), {len(split['validation'])} validate{'s' if len(split['validation']) == 1 else ''} "
            f"({_listed(split['validation'])}: early stopping, never trained on"
            + ("; whole trajectories no training flight flies" if split["by"] == "trajectory" else "") + ")")


def kept_sentence(initial: float, epochs: list[float], fine_tuned: bool) -> str:
    """What is kept when no epoch's validation loss beat the start's."""
    best = min(epochs) if epochs else float("nan")
    return (f"no epoch improved the validation loss ({initial:.4g} at the start, {best:.4g} at best over "
            f"{len(epochs)} epoch(s)): the weights at the start are kept, "
            + ("the vehicle's own residual, unchanged by this training" if fine_tuned else
               "a network of zero output (the hybrid flies as the vehicle without a residual)"))


def change_sentence(H: int, val: dict) -> str:
    """The hybrid's validation error at h = H against the vehicle's, per signal (``val``: the ratios to
    rate_frozen of ``vehicle`` and ``hybrid``), each change with its numbers."""
    from ..rollout import QUANTITIES

    v, h = val["vehicle"], val["hybrid"]
    known = [q for q in QUANTITIES if v[q] is not None and h[q] is not None]
    lower = [q for q in known if h[q] < v[q]]
    higher = [q for q in known if h[q] > v[q]]
    same = [q for q in known if h[q] == v[q]]
    change = lambda q: f"{q} ({v[q]:.4g} -> {h[q]:.4g} x rate_frozen, {100 * (h[q] / v[q] - 1):+.2g} %)"  # noqa: E731
    parts = []
    if lower:
        parts.append("lowers the validation error of " + _listed([change(q) for q in lower]))
    if higher:
        parts.append("raises that of " + _listed([change(q) for q in higher]))
    if same:
        parts.append(("leaves " if parts else "leaves the validation error of ") + _listed(same)
                     + " equal to the vehicle's to the last bit")
    missing = [q for q in QUANTITIES if q not in known]
    if missing:
        parts.append(f"has no validation error of {_listed(missing)}")
    return f"At h = {H} the residual " + ("; it ".join(parts) if parts else "cannot be compared") + "."


def report(doc: dict) -> str:
    from ..rollout import QUANTITIES

    H = doc["horizon"]
    val, mae = doc["validation"]["ratio_to_rate_frozen_at_H"], doc["validation"]["mae"]
    hs = list(next(iter(next(iter(mae.values())).values())))
    fl = doc["flights"]
    split = {"by": fl["validation_by"], "training": fl["training"], "validation": fl["validation"],
             **({"validation_from_s": fl["validation_from_s"]} if fl["validation_by"] == "time" else {})}
    where = (f"{len(fl['validation'])} whole validation flight(s) ({_listed(fl['validation'])})"
             + (", whole trajectories no training flight flies" if fl["validation_by"] == "trajectory" else "")
             if fl["validation_by"] in ("flight", "trajectory") else
             f"the flight's time from {fl['validation_from_s']:.2f} s on")
    fine_tuned = doc["network"]["start"].startswith("fine")
    losses = [e["val_loss"] for e in doc["loss_per_epoch"]]
    best = min([doc["initial_loss"]["val_loss"]] + losses)
    if doc["epochs"]["best"] == 0:
        training = (f"Training: {doc['epochs']['run']} epoch(s) ({doc['epochs']['stopped']}), "
                    f"{doc['wall_s']['training']:.1f} s; " + kept_sentence(doc["initial_loss"]["val_loss"], losses,
                                                                            fine_tuned) + ".")
    else:
        training = (f"Training: {doc['epochs']['run']} epoch(s) ({doc['epochs']['stopped']}), the weights of epoch "
                    f"{doc['epochs']['best']} kept, {doc['wall_s']['training']:.1f} s; validation loss "
                    f"{doc['initial_loss']['val_loss']:.4f} at the start ("
                    + ("the vehicle's own residual, fine-tuned" if fine_tuned else "the vehicle without a residual")
                    + f"), {best:.4f} with the kept weights.")
    lines = [f"# Residual trained through the rollout ({len(fl['training'])} training flight(s))", "",
             split_sentence(split)[0].upper() + split_sentence(split)[1:] + ".", "",
             f"A {doc['network']['activation']} MLP {doc['network']['layers']} from {', '.join(doc['network']['inputs'])} "
             f"to a body force and torque, added to `{doc['vehicle']}` at every evaluation of the dynamics and "
             f"trained by back-propagating the {H}-step rollout loss (RK4, measured rotor speeds held) on "
             f"{doc['windows']['training']} training windows; early stopping on {doc['windows']['validation']} "
             f"windows of {where}. Loss: {doc['loss']['formula']}; signal weights "
             + ", ".join(f"{q} {w:g}" for q, w in doc["loss"]["signal_weights"].items())
             + f", step weights ∝ h^{doc['loss']['horizon_power']:g}.", "", training,
             "", "![training curve](figures/training_curve.png)", "",
             "## Validation windows (the compiled rollout of `qr evaluate`)", "",
             "MAE per step h: p (m), v (m/s), R (rad), w (rad/s); the ratio to `rate_frozen` at h = H.", ""]
    head = ["model"] + [f"{q}@{h}" for q in QUANTITIES for h in hs] + [f"{q} / rate_frozen" for q in QUANTITIES]
    lines += ["| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
    fmt = lambda x: "–" if x is None else f"{x:.4g}"  # noqa: E731
    for m in ("rate_frozen", "vehicle", "hybrid"):
        cells = [fmt(mae[m][q][h]) for q in QUANTITIES for h in hs] + [fmt(val[m][q]) for q in QUANTITIES]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines += ["", change_sentence(H, val) + " These are the windows that stopped the training: judge the model on "
              "held-out flights with `qr evaluate`.", ""]
    return "\n".join(lines)


def _track(name: str, parent_id, doc: dict, out: Path, net, inputs) -> None:
    """One MLflow run (experiment ``qr-learn``): settings, loss per epoch, validation MAE per h, the model."""
    import torch

    from .. import tracking
    from ..rollout import QUANTITIES

    tags = {"qr.run": name, "qr.kind": "residual"}
    if parent_id:
        tags["mlflow.parentRunId"] = parent_id
    with tracking.run("learn", name, config={"learn": doc["config"]["learn"], "seed": doc["seed"],
                                             "evaluate": doc["config"]["evaluate"]},
                      inputs=inputs, tags=tags) as run:
        for e in doc["loss_per_epoch"]:
            run.metrics({"train_loss": e["train_loss"], "val_loss": e["val_loss"]}, step=e["epoch"])
        for model in ("vehicle", "hybrid"):
            for q in QUANTITIES:
                for h, x in doc["validation"]["mae"][model][q].items():
                    run.metrics({f"val.{model}.{q}_mae": x}, step=int(h))
                run.metrics({f"val.{model}.{q}_ratio": doc["validation"]["ratio_to_rate_frozen_at_H"][model][q]})
        run.metrics({"train_wall_s": doc["wall_s"]["training"], "best_epoch": doc["epochs"]["best"]})
        for p in ("training.json", "report.md", "hybrid_vehicle.yaml", "residual.npz"):
            run.artifact(out / p)
        module = mlflow_module(net)
        X = np.asarray(net.input_mean.numpy()[None, :] + net.input_scale.numpy()[None, :]
                       * np.linspace(-1, 1, 5)[:, None])
        with torch.no_grad():
            y = module(torch.as_tensor(X)).numpy()
        run.model("pytorch", module, X, y, [f"torch=={torch.__version__.split('+')[0]}"])


def mlflow_module(net):
    """A self-contained torch module of the residual (features φ → body wrench), for ``mlflow.pytorch``:
    the input normalisation and the output scale as fixed affine layers around the MLP."""
    import copy

    import torch

    def affine(scale, shift):
        layer = torch.nn.Linear(len(scale), len(scale), dtype=torch.float64)
        with torch.no_grad():
            layer.weight.copy_(torch.diag(torch.as_tensor(scale, dtype=torch.float64)))
            layer.bias.copy_(torch.as_tensor(shift, dtype=torch.float64))
        return layer

    act = torch.nn.Tanh if net.activation == "tanh" else torch.nn.ReLU
    layers = []
    for k, layer in enumerate(net.layers):
        layers.append(copy.deepcopy(layer))
        if k < len(net.layers) - 1:
            layers.append(act())
    mean, scale = net.input_mean.numpy(), net.input_scale.numpy()
    out = net.output_scale.numpy()
    return torch.nn.Sequential(affine(1 / scale, -mean / scale), *layers, affine(out, np.zeros_like(out))).eval()


# ---- the command line: one run, or a Hydra multirun (-m) ------------------------------------------

def _quoted(s: str) -> str:
    return "'" + str(s).replace("\\", "\\\\").replace("'", "\\'") + "'"


def main(flights, vehicle, out, rest, force: bool = False) -> None:
    """``qr learn residual``: ``rest`` holds the Hydra overrides and ``-m`` / ``--multirun``."""
    multirun = any(a in ("-m", "--multirun") for a in rest)
    overrides = [a for a in rest if a not in ("-m", "--multirun")]
    bad = [a for a in overrides if a.startswith("-")]
    if bad:
        raise QrInputError(bad[0], "unknown option", "give KEY=VALUE overrides, and -m for a sweep")
    if not multirun:
        run_residual(flights, vehicle, out, overrides, force=force)
        return
    from ..outputs import check_out_dir

    check_out_dir(out, inputs=[*flights, vehicle], force=force, expected=(SWEEP_CSV, "multirun.yaml"))
    from ..config import selects_filter, stage_filter

    if not selects_filter(overrides):
        # the filter the windows start from is evaluate.filter's, as in a single run (compose_stage)
        named = stage_filter("evaluate", overrides)
        if "," in named:
            raise QrInputError("evaluate.filter", "a sweep over the filter is given as evaluate.filter",
                               "sweep it as filter=auto,smoother")
        overrides = [*overrides, f"filter={named}"]
    given = ["learn=residual", f"learn.flights=[{','.join(_quoted(f) for f in flights)}]",
             f"learn.vehicle={_quoted(vehicle)}", f"learn.out={_quoted(out)}", f"learn.force={str(force).lower()}",
             f"hydra.sweep.dir={_quoted(out)}", "hydra.sweep.subdir='job${hydra.job.num}'"]
    argv, sys.argv = sys.argv, ["qr learn residual", "-m", *given, *overrides]
    try:
        from ..config import hydra_app

        hydra_app("learn residual", _job)
    finally:
        sys.argv = argv


def _job(cfg) -> float:
    """One job of a sweep (Hydra calls it with the composed tree)."""
    from hydra.core.hydra_config import HydraConfig

    hc = HydraConfig.get()
    learn = cfg.learn
    out = Path(learn.out)
    name = f"job{int(hc.job.num)}"
    parent = out / PARENT_FILE
    parent_id = parent.read_text().strip() if parent.exists() else None
    doc = run_residual(list(learn.flights), learn.vehicle, out / name, force=bool(learn.force), cfg=cfg,
                       run_name=name, parent_id=parent_id)
    return float(min(e["val_loss"] for e in doc["loss_per_epoch"]))


def collect(out, since: float = 0.0) -> "pd.DataFrame":  # noqa: F821
    """One row per job of a sweep (its training.json written after ``since``, a time stamp): settings,
    epochs, best validation loss and ratios at H."""
    import json

    import pandas as pd

    from ..rollout import QUANTITIES

    rows = []
    for p in sorted(Path(out).glob("job*/training.json"), key=lambda p: int(p.parent.name[3:])):
        if p.stat().st_mtime < since:  # a job of an earlier sweep into the same folder
            continue
        d = json.loads(p.read_text())
        row = {"job": p.parent.name, **{k: v for k, v in d["config"]["learn"].items()
                                       if not isinstance(v, (list, dict))},
               "signal_weights": d["loss"]["signal_weights"], "inputs": ",".join(d["network"]["inputs"]),
               "epochs": d["epochs"]["run"], "best_epoch": d["epochs"]["best"],
               "val_loss": min([d["initial_loss"]["val_loss"]] + [e["val_loss"] for e in d["loss_per_epoch"]]),
               "train_s": d["wall_s"]["training"]}
        for m in ("vehicle", "hybrid"):
            for q in QUANTITIES:
                row[f"{m}.{q}_ratio"] = d["validation"]["ratio_to_rate_frozen_at_H"][m][q]
        rows.append(row)
    return pd.DataFrame(rows)


def _is_mine(config) -> bool:
    try:
        return config.hydra.job.name == JOB
    except Exception:
        return False


class ResidualSweep(SweepCallback):
    """A ``qr learn residual -m`` multirun: one MLflow parent run, ``OUTDIR/sweep.csv`` at the end (the job
    with the lowest validation loss tagged; never chosen on held-out flights: none are read)."""

    def reset(self) -> None:
        super().reset()
        self._run = None
        self._started = 0.0

    def on_multirun_start(self, config, **kwargs) -> None:
        if not _is_mine(config):
            return
        import atexit

        from .. import tracking
        from ..atomic import write_text

        self._started = time.time()
        out = Path(config.learn.out)
        out.mkdir(parents=True, exist_ok=True)
        params = {"sweep": f"residual {out.name}", "overrides": " ".join(config.hydra.overrides.task)}
        self._cm = tracking.run("learn", params["sweep"], config=params,
                                tags={"qr.sweep": params["sweep"], "qr.parent": "true", "qr.kind": "residual"})
        self._run = self._cm.__enter__()
        write_text(out / PARENT_FILE, self._run.id + "\n")  # (a reader never finds it empty)
        atexit.register(self._close, RuntimeError("a job of the sweep failed"))

    def on_multirun_end(self, config, **kwargs) -> None:
        if self._cm is None:
            return
        from ..atomic import _write_marker, atomic_path

        out = Path(config.learn.out)
        runs = collect(out, self._started)
        with atomic_path(out / SWEEP_CSV) as tmp:
            runs.to_csv(tmp, index=False)
        # a qr output (Hydra's multirun.yaml too): a later sweep may replace them
        _write_marker(out, [SWEEP_CSV] + (["multirun.yaml"] if (out / "multirun.yaml").exists() else []),
                      "qr learn residual -m")
        if len(runs):
            best = runs.loc[runs["val_loss"].idxmin()]
            self._run.tags({"qr.best_job": best["job"]})
            self._run.metrics({"jobs": len(runs), "best_val_loss": best["val_loss"]})
        self._run.artifact(out / SWEEP_CSV)
        (out / PARENT_FILE).unlink(missing_ok=True)
        self._close(None)

