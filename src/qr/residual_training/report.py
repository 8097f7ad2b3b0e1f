"""report.md and figures/training_curve.png of a :class:`.training.ResidualTraining`."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ..rollout import QUANTITIES
from .sentences import listed, change_sentence, kept_sentence, split_sentence

if TYPE_CHECKING:
    from .training import ResidualTraining


def _training(r: ResidualTraining) -> str:
    """The training paragraph: epochs, why it stopped, the loss at the start and with the kept weights."""
    t = r.trained
    losses = [e["val_loss"] for e in t.epochs]
    head = f"Training: {len(t.epochs)} epoch(s) ({t.stopped}), "
    if t.best_epoch == 0:
        return head + f"{t.wall_s:.1f} s; " + kept_sentence(t.initial["val_loss"], losses, r.fine_tuned) + "."
    return (head + f"the weights of epoch {t.best_epoch} kept, {t.wall_s:.1f} s; validation loss "
            f"{t.initial['val_loss']:.4f} at the start ("
            + ("the vehicle's own residual, fine-tuned" if r.fine_tuned else "the vehicle without a residual")
            + f"), {min([t.initial['val_loss']] + losses):.4f} with the kept weights.")


def report(r: ResidualTraining) -> str:
    """report.md: the split, the network and its loss, the training, the validation windows' errors."""
    from .document import LOSS_FORMULA

    H, sp, t, val, mae = r.horizon, r.split, r.trained, r.validation.ratio, r.validation.mae
    where = (f"{len(sp.validation)} whole validation flight(s) ({listed(list(sp.validation))})"
             + (", whole trajectories no training flight flies" if sp.by == "trajectory" else "")
             if sp.by in ("flight", "trajectory") else f"the flight's time from {sp.validation_from_s:.2f} s on")
    said = split_sentence(sp.record())
    lines = [f"# Residual trained through the rollout ({len(sp.training)} training flight(s))", "",
             said[0].upper() + said[1:] + ".", "",
             f"A {t.net.activation} MLP {r.residual.layers} from {', '.join(t.net.inputs)} "
             f"to a body force and torque, added to `{r.vehicle_file}` at every evaluation of the dynamics and "
             f"trained by back-propagating the {H}-step rollout loss (RK4, measured rotor speeds held) on "
             f"{t.windows['train']} training windows; early stopping on {t.windows['val']} "
             f"windows of {where}. Loss: {LOSS_FORMULA}; signal weights "
             + ", ".join(f"{q} {w:g}" for q, w in r.signal_weights.items())
             + f", step weights ∝ h^{r.settings.learn.horizon_power:g}.", "", _training(r),
             "", "![training curve](figures/training_curve.png)", "",
             "## Validation windows (the compiled rollout of `qr evaluate`)", "",
             "MAE per step h: p (m), v (m/s), R (rad), w (rad/s); the ratio to `rate_frozen` at h = H.", ""]
    hs = r.validation.steps
    head = ["model"] + [f"{q}@{h}" for q in QUANTITIES for h in hs] + [f"{q} / rate_frozen" for q in QUANTITIES]
    lines += ["| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
    fmt = lambda x: "–" if x is None else f"{x:.4g}"  # noqa: E731
    for m in ("rate_frozen", "vehicle", "hybrid"):
        cells = [fmt(mae[m][q][h]) for q in QUANTITIES for h in hs] + [fmt(val[m][q]) for q in QUANTITIES]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines += ["", change_sentence(H, val) + " These are the windows that stopped the training: judge the model on "
              "held-out flights with `qr evaluate`.", ""]
    return "\n".join(lines)


def curve_figure(r: ResidualTraining, path: Path) -> None:
    """The training and validation loss per epoch, the kept epoch marked."""
    from ..report import figures

    t = r.trained
    fig, ax = figures.subplots(1, 1, figsize=(5.5, 3.4), layout="constrained")
    x = [0] + [e["epoch"] for e in t.epochs]
    ax.plot(x, [t.initial["train_loss"]] + [e["train_loss"] for e in t.epochs], label="training", color="C0")
    ax.plot(x, [t.initial["val_loss"]] + [e["val_loss"] for e in t.epochs], label="validation", color="C1")
    ax.axvline(t.best_epoch, color="0.5", ls=":", label=f"kept (epoch {t.best_epoch})")
    ax.set_xlabel("epoch (count; 0: " + ("the vehicle's own residual)" if r.fine_tuned
                                        else "the vehicle without the residual)"))
    ax.set_ylabel("rollout loss (ratio: weighted MAE / rate_frozen's)")
    ax.legend(fontsize=7)
    figures.save(fig, path)
