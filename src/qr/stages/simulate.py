"""Stage ``simulate``: the simulation study (thesis Chapter 5), ``qr simulate [simulate=thesis]
[simulate.task=tracking|stability|all]``.

Each study (:func:`qr.sim.simulation.run`: tracking, stability) is an MLflow parent run (experiments
``qr-simulate``, ``qr-stability``) with every closed loop a child run; its table goes to
``results/simulation/`` (CSV + Markdown), its figures to ``results/figures/``.  The force-model specs of
the config: :mod:`qr.sim.specs`.
"""

from __future__ import annotations

import logging
from pathlib import Path

from ..sim.simulation import FIGURES, TITLES, figures, metrics, run, studies

EXPERIMENTS = {"tracking": "simulate", "stability": "stability"}  # a study's MLflow experiment (qr-<name>)


def write_study(sim: dict, study: str, table_path, figure_paths: dict | None = None, inputs=()):
    """Run ``study`` and write its table (CSV + .md, ``table_path``) and figures (default: ``figures/`` beside
    the table's folder); one MLflow run, a child per closed loop.  The study's result."""
    from .. import tracking
    from ..report.tables import write_table

    stage = EXPERIMENTS[study]
    figure_paths = figure_paths or {k: Path(table_path).parents[1] / "figures" / v for k, v in FIGURES[study].items()}
    with tracking.run(stage, f"{stage}:{sim.get('name', 'sim')}", sim, inputs) as handle:
        def child(loop):
            with tracking.run(stage, loop.name, loop.params, parent=handle,
                              tags={"qr.status": loop.metrics.get("status", "")}) as r:
                r.metrics({k: v for k, v in loop.metrics.items() if isinstance(v, (int, float))})

        result = run(sim, study, child)
        write_table(result.table, table_path, title=TITLES[study])
        figures(result, figure_paths)
        if metrics(result):
            handle.metrics(metrics(result))
        for p in [table_path, *figure_paths.values()]:
            handle.artifact(p)
    return result


def _main(cfg) -> None:
    from ..config import to_dict

    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    c = to_dict(cfg)
    for study in studies(c["simulate"].get("task", "all")):
        write_study(c["simulate"], study, Path(c["results"]) / "simulation" / f"{study}.csv")


def main() -> None:
    """``qr simulate`` / ``python -m qr.simulate``."""
    from ..config import hydra_app

    hydra_app("simulate", _main)


if __name__ == "__main__":
    main()
