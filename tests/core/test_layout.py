"""The house as the code map (docs/code-map.md; the README's short one) draws it: each stage found by its
name, no import cycles.

Issue 14's done-when: a newcomer finds each stage's module, command, config group, rule file, tests
and docs page by the stage's name alone; the code map names every module.  Issue 28's: no import
cycle of any length (a graph search over every import of src/qr, those inside functions included).
"""

import ast
import graphlib
import importlib
import re

import pytest

from conftest import ROOT

STAGES = ("ingest", "filter", "learn", "diagnose", "simulate", "evaluate", "replay")
SRC = ROOT / "src" / "qr"


@pytest.mark.parametrize("stage", STAGES)
def test_each_stage_is_found_by_its_name(stage):
    module = importlib.import_module(f"qr.stages.{stage}")
    assert module.__doc__ and stage in module.__doc__.split("\n")[0].lower()
    # python -m qr.<stage>: a module of that name or a package with __main__
    assert (SRC / f"{stage}.py").exists() or (SRC / stage / "__main__.py").exists()
    group = {"ingest": "data"}.get(stage, stage)  # ingest's settings: the data sets (and vehicles)
    assert list((ROOT / "conf" / group).glob("*.yaml")), f"no config group conf/{group}/"
    assert (ROOT / "workflow" / "rules" / f"{stage}.smk").exists()
    assert list((ROOT / "tests" / stage).glob("test_*.py")), f"no tests/{stage}/"
    assert (ROOT / "docs" / f"{stage}.md").exists()


def test_qr_export_is_found_like_a_stage():
    """``qr export`` (issue 27) has no settings of its own (no config group); the rest of the house it has."""
    module = importlib.import_module("qr.stages.export")
    assert module.__doc__ and "export" in module.__doc__.split("\n")[0].lower()
    assert (SRC / "export" / "__main__.py").exists()
    assert (ROOT / "workflow" / "rules" / "export.smk").exists()
    assert list((ROOT / "tests" / "export").glob("test_*.py"))
    assert (ROOT / "docs" / "export.md").exists()


def _imports() -> dict[str, set[str]]:
    """Every module of src/qr and the qr modules it imports (at the top or inside a function)."""
    mods = {}
    for p in SRC.rglob("*.py"):
        parts = list(p.relative_to(SRC.parent).with_suffix("").parts)
        mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    graph = {}
    for name, path in mods.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                base = ".".join(package[:len(package) - node.level + 1] + ([node.module] if node.module else [])) \
                    if node.level else node.module
                for a in node.names:
                    deps.add(f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base)
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names)
        graph[name] = {d for d in deps if d in mods and d != name}
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """An import cycle of any length in ``graph`` (module -> modules it imports), or None."""
    try:
        list(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as e:
        return e.args[1]
    return None


def test_the_cycle_search_finds_a_cycle_of_any_length():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"d"}, "d": {"a"}, "e": {"a"}})[0] in "abcd"
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": set(), "d": {"a", "c"}}) is None


def test_no_import_cycle_of_any_length():
    """Imports inside functions count: they hide a cycle from import time, not from the design."""
    graph = _imports()
    assert len(graph) > 50 and "qr.rollout" in graph["qr.stages.evaluate"]  # the walk sees imports
    assert "qr.config" in graph["qr.stages.diagnose"]  # ... those inside functions too
    cycle = _cycle(graph)
    assert cycle is None, f"an import cycle: {' -> '.join(cycle)}"


def test_only_the_stages_and_their_helpers_import_the_stages():
    """Libraries take and return arrays and data frames; the stages (and the CLI, the
    ``python -m`` entries and the scenarios that run whole diagnoses) call the libraries, not back."""
    callers_allowed = {"qr.cli", "qr.sim.scenarios"}
    for name, deps in _imports().items():
        if name.startswith("qr.stages") or name in callers_allowed:
            continue
        assert not {d for d in deps if d.startswith("qr.stages")}, f"{name} imports a stage"


def _code_map() -> str:
    """The module map of docs/code-map.md: its first fenced block."""
    text = (ROOT / "docs" / "code-map.md").read_text()
    start = text.index("```")
    return text[start:text.index("```", start + 3) + 3]


def _unnamed(code_map: str) -> list[str]:
    """The modules of src/qr (package markers and the stages' folder aside) that ``code_map`` does not name."""
    missing = []
    for p in sorted(SRC.rglob("*.py")):
        if p.name in ("__init__.py", "__main__.py") or p.parent.name == "stages":
            continue
        if not re.search(rf"(?<![\w/]){re.escape(p.stem)}(\.py)?\b", code_map):
            missing.append(str(p.relative_to(SRC)))
    return missing


def test_the_code_map_names_every_module():
    missing = _unnamed(_code_map())
    assert not missing, f"docs/code-map.md's module map does not name {missing}"


def test_the_code_map_check_finds_a_module_left_out():
    """The check above can fail: the map with one module's name removed is caught, naming that module."""
    code_map = _code_map()
    assert "rollout_torch.py" in code_map and "background.py" in code_map
    assert _unnamed(code_map.replace("rollout_torch.py", "")) == ["rollout_torch.py"]
    assert _unnamed(code_map.replace("background.py", "")) == ["report/background.py"]


def test_the_readme_code_map_names_every_package_and_links_the_full_map():
    """The README keeps a short map (docs/spec/layout.md's picture): every package of src/qr by its folder,
    and the link to the per-module map."""
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## Code map"):]
    section = section[:section.index("\n## ", 3)] if "\n## " in section[3:] else section
    assert "docs/code-map.md" in section
    packages = sorted(p.parent.name for p in SRC.glob("*/__init__.py") if p.parent.name != "stages")
    missing = [f"{name}/" for name in packages if f"{name}/" not in section]
    assert not missing, f"the README's code map does not name the packages {missing}"
