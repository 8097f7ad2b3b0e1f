"""Every config file composes (a broken default or experiment fails here, not minutes into a run), and
named experiments merge in the order given."""

import pytest

from conftest import ROOT
from qr.config import compose

GROUPS = ["data", "filter", "learn", "split", "model", "simulate", "diagnose", "evaluate", "sweep"]
CASES = [f"{g}={p.stem}" for g in GROUPS for p in sorted((ROOT / "conf" / g).glob("*.yaml"))]
CASES += [f"+experiment=[{p.stem}]" for p in sorted((ROOT / "conf" / "experiment").glob("*.yaml"))]


@pytest.mark.parametrize("override", CASES)
def test_every_config_file_composes(override):
    cfg = compose([override])
    assert cfg.seed == 0 and cfg.diagnose.horizon_s > 0


def test_experiments_merge_in_the_order_given():
    """The workflow's per-flight diagnoses: the short-flight settings, then the per-flight ones (later
    wins on block_s), then the carried thrust map; the defaults stay where no experiment sets a key."""
    base = compose([]).diagnose
    d = compose(["+experiment=[crazyflie_short_flights,per_flight,thrust_map_fixed]"]).diagnose
    assert (d.gap_s, d.horizon_s, d.block_s, d.trim_s, d.selection.folds) == (0.5, 0.5, 0.5, 0.3, 3)
    assert list(d.exclude) == ["thrust_gain", "motor_imbalance"]
    assert d.train_fraction == base.train_fraction and d.candidates == base.candidates
    swapped = compose(["+experiment=[per_flight,crazyflie_short_flights]"]).diagnose
    assert swapped.block_s == 1.0 and swapped.trim_s == 0.3
