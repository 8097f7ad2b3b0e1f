"""training.json (schema ``qr.residual/1``, docs/spec/hybrid.md) of a :class:`.training.ResidualTraining`."""

from __future__ import annotations

from typing import TYPE_CHECKING


if TYPE_CHECKING:
    from .training import ResidualTraining

SCHEMA = "qr.residual/1"
LOSS_FORMULA = ("sum_s lambda_s sum_h w_h MAE_{s,h} / ref_s; ref_s = rate_frozen's mean MAE over h on the training "
                "windows")


def document(r: ResidualTraining) -> dict:
    import torch

    from ..ensemble import BANDS_FILE, START

    rcfg, t, sp, v = r.settings.learn, r.trained, r.split, r.validation
    return {
        "schema": SCHEMA,
        "vehicle": r.vehicle_file,
        "flights": {"training": r.split_training,
                    "validation": [f for f in r.flights if f in sp.validation],
                    "validation_by": sp.by,
                    **({"validation_from_s": sp.validation_from_s} if sp.by == "time" else {})},
        "windows": {"training": t.windows["train"], "validation": t.windows["val"], "stride": rcfg.stride},
        "horizon": r.horizon,
        "loss": {"signal_weights": r.signal_weights, "horizon_power": rcfg.horizon_power,
                 "horizon_weights": rcfg.horizon_weights().tolist(), "reference": t.reference,
                 "formula": LOSS_FORMULA},
        "network": {"inputs": list(t.net.inputs), "layers": r.residual.layers, "activation": t.net.activation,
                    "start": "fine-tuned from the vehicle's residual" if r.fine_tuned else "new, zero output"},
        "epochs": {"run": len(t.epochs), "best": t.best_epoch, "stopped": t.stopped, "limit": rcfg.epochs,
                   "patience": rcfg.patience, "skipped_steps": t.skipped_steps},
        "seed": r.settings.seed,
        "wall_s": {"training": t.wall_s, "estimates": r.estimate_s},
        "initial_loss": t.initial,
        "loss_per_epoch": t.epochs,
        "validation": {"mae": {m: {q: {str(h): x for h, x in by_h.items()} for q, by_h in by_q.items()}
                               for m, by_q in v.mae.items()},
                       "ratio_to_rate_frozen_at_H": v.ratio,
                       "models": {"vehicle": "the vehicle without the residual", "hybrid": "with the residual",
                                  "rate_frozen": "the benchmark's physics baseline (qr evaluate's reference)"}},
        "config": r.settings.given,
        "software": {"torch": torch.__version__, "threads": t.threads},
        "residual_size": r.size.record(),
        **({"ensemble": {
            "members": rcfg.members, "file": BANDS_FILE, "scale": r.ensemble.scale,
            "scale50": r.ensemble.scale50,
            "scale_horizon": r.settings.evaluate.horizon, "calibrated_on": r.ensemble.calibrated_on,
            "wall_s": r.ensemble.wall_s, "start": START, "member_epochs": rcfg.member_epochs,
            "patience": rcfg.patience, "jobs": r.ensemble.jobs,
            "epochs_run": [m.epochs_run for m in r.ensemble.members],
            "best_epochs": [m.best_epoch for m in r.ensemble.members],
            "resampled": "by flight" if sp.by != "time" else
                         "not resampled: one flight (members differ by their seeds)"}} if r.ensemble else {}),
    }
