"""Every config file composes (a broken default or experiment fails here, not minutes into a run), and
named experiments merge in the order given."""

import pytest

from conftest import ROOT
from qr.config import compose

GROUPS = ["data", "filter", "learn", "split", "model", "simulate", "diagnose", "evaluate", "sweep", "replay", "controller"]
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


@pytest.mark.parametrize("group", ["diagnose", "evaluate"])
def test_structured_groups_write_their_defaults_once(group):
    """The group's YAML only selects its structured config: every default comes from the dataclass (one
    place), and a key the dataclass lacks is refused when the config is composed."""
    import dataclasses

    import yaml

    from qr.config import schemas, to_dict
    from qr.errors import QrInputError
    from qr.config import compose_stage

    doc = yaml.safe_load((ROOT / "conf" / group / "default.yaml").read_text())
    assert doc == {"defaults": ["schema", "_self_"]}
    assert to_dict(compose([])[group]) == dataclasses.asdict(schemas()[group]())
    with pytest.raises(QrInputError, match=f"{group}.no_such_key"):
        compose_stage([f"{group}.no_such_key=1"], group, "x")


@pytest.mark.parametrize("override, message", [
    ("evaluate.horizon=abc", "evaluate.horizon: 'abc' is not an integer; fix: give evaluate.horizon an integer in "
                             "[1, 100000], e.g. evaluate.horizon=50 (the default, src/qr/rollout.py)"),
    ("diagnose.selection.beam=1.5", "diagnose.selection.beam: 1.5 is not an integer"),
    ("diagnose.exclude=cg_offset", "diagnose.exclude: 'cg_offset' is not a list (write [cg_offset])"),
])
def test_a_type_error_of_a_structured_key_is_one_line_naming_key_value_and_range(override, message):
    """OmegaConf refuses the type when the config is composed; the error is qr's line, not Hydra's."""
    from qr.config import compose_stage
    from qr.errors import QrInputError

    stage = override.split(".")[0]
    with pytest.raises(QrInputError) as e:
        compose_stage([override], stage, "x")
    assert message in str(e.value) and "\n" not in str(e.value)


def test_a_switch_of_the_wrong_type_is_one_line_too():
    from qr.config import compose_stage
    from qr.errors import QrInputError

    with pytest.raises(QrInputError) as e:
        compose_stage(["filter.smoother=abc"], "diagnose", "x")
    assert str(e.value).startswith("filter.smoother: Value 'abc' is not a valid bool")
    assert "filter.smoother=false (the default, src/qr/estimation/settings.py)" in str(e.value)


def test_a_hydra_stage_gives_the_type_error_as_one_line_before_hydra_runs(tmp_path):
    """`qr filter` is a Hydra app: Hydra would print its override error as a block; qr's line comes first."""
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "qr.filter", f"filter.flight={tmp_path / 'f.csv'}",
                          "filter.nis.confidence=abc"], capture_output=True, text=True, cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.strip().count("\n") == 0
    assert res.stderr.startswith("qr filter: error: filter.nis.confidence: 'abc' is not a number")


@pytest.mark.parametrize("kind", ["thesis", "blocked", "by_flight"])
def test_each_split_kind_is_its_structured_config(kind):
    """conf/split/<kind>.yaml writes no default; an option of another kind is refused when composed."""
    import dataclasses

    import yaml

    from qr.config import to_dict
    from qr.datasets import SPLITS

    doc = yaml.safe_load((ROOT / "conf" / "split" / f"{kind}.yaml").read_text())
    assert doc == {"defaults": [f"schema_{kind}", "_self_"]}
    assert to_dict(compose([f"split={kind}"]).split) == dataclasses.asdict(SPLITS[kind]())
    other = "gap_s" if kind != "blocked" else "seed"
    with pytest.raises(Exception, match=other):
        compose([f"split={kind}", f"split.{other}=1"])
