"""The workflow's replays (workflow/rules/replay.smk): each flight set's held-out flights (those the rollout
holds out, with a trajectory in the data set's file: :mod:`qr.replay.sets`) replayed under the set's
controller with every model the workflow wrote for it, and one table of them (``results/tables/replay.csv``).  The held-out flights repeat trajectories the models were trained on (the same
figure-8 at the same time scales): an interpolation figure, said so in the table's title."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd


def replay_set(logs, evaluation, learned: list, learned_labels: list[str], out, controller: str, overrides,
               track: str | None = None) -> dict:
    """Replay ``logs`` with the models of the held-out rollout (``evaluation``: its folder; its vehicle files
    and labels) and the rollout-trained residuals (``learned``, labelled ``learned_labels``)."""
    from .replay import run_replay

    doc = json.loads((Path(evaluation) / "evaluation.json").read_text())
    vehicles = [*doc["vehicles"], *map(str, learned)]
    labels = [*doc["labels"].values(), *learned_labels]
    return run_replay(list(map(str, logs)), vehicles, controller, out, overrides, labels=labels, track=track,
                      log=lambda m: None)


SUMMARY_COLUMNS = ["set", "flights", "model", "position RMSE (m)", "max (m)", "parts at (s)", "attitude RMSE (deg)",
                   "rotor speeds RMSE (%)", "thrust RMSE (N)", "position / nominal", "attitude / nominal",
                   "lost at (s)"]


def summary_table(replay_dirs: dict, table) -> pd.DataFrame:
    """The sets' replays side by side: per model the RMSE of position, attitude, rotor speeds and thrust over
    the replayed flights, when it parts from the log, and its position and attitude error over the nominal
    model's (the first)."""
    from ..report.tables import write_table

    rows = []
    for name, d in replay_dirs.items():
        doc = json.loads((Path(d) / "replay.json").read_text())
        models = doc["models"]
        first = next(iter(models.values()))
        for v, m in models.items():
            rows.append({
                "set": name, "flights": len(doc["flights"]), "model": doc["labels"][v],
                "position RMSE (m)": m["position"]["rmse_m"], "max (m)": m["position"]["max_m"],
                "parts at (s)": m["position"]["parts_at_s"], "attitude RMSE (deg)": m["attitude"]["rmse_deg"],
                "rotor speeds RMSE (%)": m["rotor_speed"]["rmse_percent"], "thrust RMSE (N)": m["thrust"]["rmse_N"],
                "position / nominal": _ratio(m["position"]["rmse_m"], first["position"]["rmse_m"]),
                "attitude / nominal": _ratio(m["attitude"]["rmse_deg"], first["attitude"]["rmse_deg"]),
                "lost at (s)": m["diverged_at_s"]})
    df = pd.DataFrame(rows, columns=SUMMARY_COLUMNS)  # a workflow without a replayed set: the header alone
    write_table(df, table, title="Closed-loop replay of held-out flights under the vehicle's own controller (qr "
                                 "replay; the held-out flights repeat the training trajectories: interpolation)")
    return df


def _ratio(x, ref):
    return None if x is None or not ref else x / ref
