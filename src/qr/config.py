"""Hydra configuration: one tree in ``conf/`` (``config.yaml`` + one group per stage).

The Hydra stages (``qr filter | learn | simulate``) run through :func:`hydra_app`; library code and
``qr diagnose`` / ``qr evaluate`` compose the same tree with overrides.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import TypeAlias

from .shipped import CONF_DIR

ROOT = Path(__file__).resolve().parents[2]

# a config group as composed (OmegaConf's plain container, :func:`to_dict`): the keys are the group's own
# (conf/<group>/*.yaml, any experiment's additions), recorded verbatim in a command's JSON as ``config``
Plain: TypeAlias = "str | int | float | bool | None | list[Plain] | dict[str, Plain]"
Group: TypeAlias = "dict[str, Plain]"


def compose(overrides=()):
    """The resolved config with Hydra-style overrides (``['model=gpr', 'seed=3']``).

    Composed once per set of overrides and process (Hydra takes ~0.6 s; a workflow job diagnoses
    dozens of flights with the same overrides); each caller gets its own copy.
    """
    import copy

    return copy.deepcopy(_compose_once(tuple(overrides)))


@functools.lru_cache(maxsize=32)
def _compose_once(overrides: tuple):
    from hydra import compose as _compose
    from hydra import initialize_config_dir

    register_schemas()
    with initialize_config_dir(CONF_DIR, version_base="1.3"):
        return _compose("config", overrides=list(overrides))


def schemas() -> dict:
    """Config group -> the dataclass that is its structured config (Hydra's ConfigStore, name ``schema``):
    the one place its keys, types, defaults and allowed values are written (the YAML file of the group
    only selects it)."""
    from .diagnose.settings import DiagnoseNode
    from .estimation.settings import FilterNode
    from .rollout import EvaluateNode

    return {"diagnose": DiagnoseNode, "evaluate": EvaluateNode, "filter": FilterNode}


def kind_schemas() -> dict:
    """Groups whose options differ per kind: group -> {kind: dataclass} (ConfigStore name ``schema_<kind>``)."""
    from .datasets import SPLITS
    from .residual_fit import ResidualNode

    return {"split": SPLITS, "learn": {"residual": ResidualNode}}


@functools.lru_cache(maxsize=1)
def register_schemas() -> None:
    from hydra.core.config_store import ConfigStore

    cs = ConfigStore.instance()
    for group, node in schemas().items():
        cs.store(group=group, name="schema", node=node)
    for group, kinds in kind_schemas().items():
        for kind, node in kinds.items():
            cs.store(group=group, name=f"schema_{kind}", node=node)
    # Hydra deep-copies its config repository, and the store with it, for every composition, and `--help` composes
    # once per config group (~115 times): half of `qr filter --help`.  The copies only read the store (each read
    # copies the node it returns), so they share it; picklable (a launcher sends the store to its workers).
    cs.__deepcopy__ = functools.partial(_the_store, cs)


def _the_store(store, memo):
    return store


def _allowed(key: str):
    """The declared field (its :class:`qr.allowed.Allowed` and default) of a structured key, or None."""
    import inspect
    from dataclasses import MISSING, fields, is_dataclass

    group, *path = key.split(".")
    cls = schemas().get(group)
    if cls is None and path:  # a kind's option: the first kind that has it
        cls = next((c for c in kind_schemas().get(group, {}).values() if path[0] in {f.name for f in fields(c)}),
                   None)
    for i, name in enumerate(path):
        f = next((f for f in fields(cls) if f.name == name), None) if cls is not None and is_dataclass(cls) else None
        if f is None:
            return None
        if i < len(path) - 1:
            cls = f.default_factory if f.default_factory is not MISSING else None
            continue
        default = f.default if f.default_factory is MISSING else f.default_factory()
        source = Path(inspect.getsourcefile(cls)).resolve()
        return f.metadata.get("allowed"), default, str(source.relative_to(ROOT) if source.is_relative_to(ROOT)
                                                       else source)
    return None


def _type_error(e: Exception, overrides: list[str]):
    """A structured config's type error as qr's own one line (key, value as written, allowed values)."""
    import yaml
    from omegaconf.errors import ValidationError

    from .allowed import show
    from .errors import QrInputError

    while e is not None and not isinstance(e, ValidationError):
        e = e.__cause__ or e.__context__
    if e is None:
        return None
    key = str(getattr(e, "full_key", "") or "")
    raw = next((o.split("=", 1)[1] for o in overrides if "=" in o and o.split("=", 1)[0].lstrip("+~") == key), None)
    found = _allowed(key)
    if not key or raw is None or found is None:
        return None
    allowed, default, source = found
    if allowed is None:  # a field without declared values (a switch, a name): OmegaConf's own words
        return QrInputError(key, str(e.msg).strip().splitlines()[0], f"e.g. {key}={show(default)} (the default, {source})")
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError:
        value = raw
    try:
        allowed.check(key, value, default, source)
    except QrInputError as mine:
        return mine
    return QrInputError(key, f"{raw!r} is not allowed", f"give {key} {allowed.describe()}")


def to_dict(cfg) -> Group:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(cfg, resolve=True)


def experiments(names) -> list[str]:
    """Named experiments (``conf/experiment/``) as one Hydra override, ``['+experiment=[a,b]']`` (a config
    group is selected once; its configs merge in list order), or none."""
    names = list(names)
    return [f"+experiment=[{','.join(names)}]"] if names else []


def _key(override: str) -> str:
    return override.split("=")[0].lstrip("+~")


def selects_filter(overrides) -> bool:
    """Whether ``overrides`` select the config group ``filter`` themselves (``filter=NAME``)."""
    return any(_key(o) == "filter" for o in overrides)


def stage_filter(stage: str, overrides: list[str]) -> str:
    """The filter ``<stage>.filter`` names: the last override of it, else its structured default."""
    given = [o.split("=", 1)[1] for o in overrides if "=" in o and _key(o) == f"{stage}.filter"]
    return given[-1] if given else schemas()[stage].filter


def compose_stage(overrides, stage: str, example: str):
    """The tree for a CLI stage whose config names its filter (``<stage>.filter``, unless ``filter=`` is
    overridden); Hydra's long errors become one line (``example``: a KEY=VALUE the user can copy)."""
    from .errors import QrInputError

    overrides = list(overrides)
    try:
        if selects_filter(overrides):
            cfg = compose(overrides)
        else:  # composed once (Hydra takes ~0.5 s), with the filter the stage's key names ...
            named = stage_filter(stage, overrides)
            cfg = compose(overrides + [f"filter={named}"])
            if cfg[stage].filter != named:  # ... again where a named experiment chose another
                cfg = compose(overrides + [f"filter={cfg[stage].filter}"])
    except Exception as e:  # Hydra's errors are long; the first line says what is wrong
        mine = _type_error(e, overrides)
        if mine is not None:
            raise mine from None
        raise QrInputError("overrides", str(e).strip().splitlines()[0],
                           f"use KEY=VALUE for keys in conf/ (e.g. {example}, filter=auto)") from None
    return cfg


def _first_job(args: list[str]) -> list[str]:
    """The overrides of a command line's first job: each sweep's first value, Hydra's own keys left out."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    out = []
    for o in OverridesParser.create().parse_overrides([a for a in args if not a.startswith("-")]):
        if o.key_or_group.startswith(("hydra/", "hydra.")):
            continue
        out.append(f"{o.get_key_element()}={next(iter(o.sweep_string_iterator()))}" if o.is_sweep_override()
                   else o.input_line)
    return out


def hydra_app(stage: str, task, precheck=None) -> None:
    """Run ``task(cfg)`` as stage ``stage``'s Hydra app (overrides, ``-m`` sweeps, ``--help``, ``--cfg``).

    A user mistake (:class:`qr.errors.QrInputError`) is one line and exit status 2, as everywhere in
    ``qr``; Hydra would print a traceback.  Before Hydra makes a run or sweep folder (or a sweep its
    MLflow parent run), the first job's config is composed: a wrong type of a structured key, or what
    ``precheck(cfg)`` (a plain dict) refuses, ends there with nothing written.  ``functools.wraps``
    keeps ``task``'s module, from which Hydra names the job (the stage: ``learn``'s sweep callback acts
    only on its own multiruns).
    """
    import sys

    import hydra

    from .errors import EXIT_BAD_INPUT, QrInputError, error_line

    @functools.wraps(task)
    def entry(cfg):
        try:
            return task(cfg)
        except QrInputError as e:
            print(error_line(e, f"qr {stage}"), file=sys.stderr)
            sys.exit(EXIT_BAD_INPUT)

    register_schemas()
    args = sys.argv[1:]
    if {a for a in args if a.startswith("-")} <= {"-m", "--multirun"}:  # a run or a sweep (not --cfg, --help)
        try:
            first = _first_job(args)
            cfg = compose(first)
        except Exception as e:
            mine = _type_error(e, first) if "first" in locals() else None
            if mine is not None:
                print(error_line(mine, f"qr {stage}"), file=sys.stderr)
                sys.exit(EXIT_BAD_INPUT)
            cfg = None  # Hydra says what is wrong, as it parses the command line itself
        if cfg is not None and precheck is not None:
            try:
                precheck(to_dict(cfg))
            except QrInputError as e:
                print(error_line(e, f"qr {stage}"), file=sys.stderr)
                sys.exit(EXIT_BAD_INPUT)
    hydra.main(config_path=CONF_DIR, config_name="config", version_base="1.3")(entry)()
