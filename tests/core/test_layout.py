"""The house as the README's code map draws it: each stage found by its name, no import cycles.

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
    assert len(graph) > 50 and "qr.pieces" in graph["qr.stages.evaluate"]  # the walk sees imports
    assert "qr.diagnose.report" in graph["qr.stages.diagnose"]  # ... those inside functions too
    cycle = _cycle(graph)
    assert cycle is None, f"an import cycle: {' -> '.join(cycle)}"


def test_only_the_stages_and_their_helpers_import_the_stages():
    """Libraries take and return arrays and data frames; the stages (and the CLI, the
    ``python -m`` entries) call the libraries, not back: the scenarios diagnose through :func:`qr.diagnose.run`."""
    callers_allowed = {"qr.cli"}
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


# ---- the stages: no stage imports another; only they track ------------------------------------

STAGE_MODULES = {f"qr.stages.{s}" for s in (*STAGES, "export", "learn_residual")}  # (sweep_callback: their base)


def test_no_stage_imports_another_stage():
    graph = _imports()
    assert STAGE_MODULES <= set(graph)
    found = {(name, d) for name in STAGE_MODULES for d in graph[name] if d in STAGE_MODULES}
    assert not found, f"stage imports another stage (its workflow glue belongs in <stage>_sets.py): {sorted(found)}"


STAGE_CODE_LINES = 60  # issue 35: a stage reads, calls one library run, writes one atomic folder, tracks


def _code_lines(text: str) -> int:
    """Lines holding code: blank lines, comments and docstrings (module, class, function) not counted."""
    import io
    import tokenize

    doc = set()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.body:
            b = node.body[0]
            if isinstance(b, ast.Expr) and isinstance(b.value, ast.Constant) and isinstance(b.value.value, str):
                doc.update(range(b.lineno, b.end_lineno + 1))
    skip = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.ENCODING,
            tokenize.ENDMARKER}
    lines = set()
    for t in tokenize.generate_tokens(io.StringIO(text).readline):
        if t.type not in skip:
            lines.update(range(t.start[0], t.end[0] + 1))
    return len(lines - doc)


def test_the_code_line_count_leaves_out_docstrings_comments_and_blank_lines():
    text = ('"""Module.\n\nstill the docstring"""\n\nimport sys  # a comment\n# a comment line\n\n\n'
            'def f(a,\n      b):\n    """Doc."""\n    s = """not a\n    docstring"""\n    return s\n')
    assert _code_lines(text) == 6  # import; def (2 lines); s = (2 lines); return


@pytest.mark.parametrize("module", sorted(STAGE_MODULES))
def test_each_stage_module_is_read_run_write_track(module):
    """A stage module holds no library code: at most STAGE_CODE_LINES lines of code (its workflow glue lives
    beside it in ``<stage>_sets.py``, the computation in the library it calls)."""
    path = SRC / "stages" / f"{module.rsplit('.', 1)[1]}.py"
    n = _code_lines(path.read_text())
    assert n <= STAGE_CODE_LINES, f"{path.name}: {n} lines of code (at most {STAGE_CODE_LINES})"


def test_only_the_stages_track_mlflow_runs():
    importers = {name for name, deps in _imports().items() if "qr.tracking" in deps}
    assert importers and all(n.startswith("qr.stages.") for n in importers), sorted(importers)


# ---- every file qr writes goes through qr.atomic (write-then-rename) --------------------------

WRITE_METHODS = {"to_csv", "to_parquet", "to_json", "to_pickle", "to_feather", "to_hdf", "savefig"}
PATH_WRITES = {"write_text", "write_bytes"}  # Path methods: the path is the object
SAVERS = {("np", "save"): 0, ("np", "savez"): 0, ("np", "savez_compressed"): 0, ("numpy", "save"): 0,
          ("torch", "save"): 1, ("joblib", "dump"): 1, ("shutil", "copy"): 1, ("shutil", "copy2"): 1,
          ("shutil", "copyfile"): 1, ("shutil", "copytree"): 1, ("shutil", "move"): 1, ("os", "replace"): 1,
          ("os", "rename"): 1}
ATOMIC = {"atomic_path", "atomic_dir"}
# Writes that are not inside an atomic_path / atomic_dir of the same function, each with why it is safe
# (or what it is).  (module, function) -> reason.
UNATOMIC_WRITES = {
    ("qr.models.ann", "_save_weights"): "into the temporary folder models/base.py's save() takes from atomic_dir",
    ("qr.models.linear", "_save_weights"): "the same",
    ("qr.models.gpr", "_save_weights"): "the same",
    ("qr.residual", "save_weights"): "into the temporary folder or path of its callers' atomic_dir / atomic_path",
    ("qr.residual", "weights_bytes"): "into memory (an io.BytesIO): no file",
    ("qr.report.background", "collect"): "moves a figure drawn in a private temporary folder into the caller's "
                                         "atomic_dir (the diagnosis's figures folder)",
    ("qr.tracking", "_store_lock"): "the MLflow store's lock file (flock): no output, never read",
    ("qr.errors", "job_log"): "a workflow job's log (the rule's `log:` file), written as the job goes: no output",
}


def _base(node):
    """The name a path expression is built from (``tmp`` in ``Path(tmp / "a").with_suffix(".b")``), or None."""
    while True:
        if isinstance(node, ast.Name):
            return node.id
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
            node = node.left
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("Path", "str") \
                and node.args:
            node = node.args[0]
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):  # tmp.with_suffix(...)
            node = node.func.value
        elif isinstance(node, ast.Attribute):  # tmp.parent
            node = node.value
        else:
            return None


def _writes(func):
    """(line, target path expression) of every file write in ``func``."""
    out = []
    for n in ast.walk(func):
        if not isinstance(n, ast.Call):
            continue
        f = n.func
        if isinstance(f, ast.Name) and f.id == "open" and n.args:
            mode = n.args[1] if len(n.args) > 1 else next((k.value for k in n.keywords if k.arg == "mode"), None)
            if isinstance(mode, ast.Constant) and set(str(mode.value)) & set("wax+"):
                out.append((n.lineno, n.args[0]))
        elif isinstance(f, ast.Attribute):
            if f.attr in PATH_WRITES:
                out.append((n.lineno, f.value))
            elif f.attr in WRITE_METHODS and n.args:
                out.append((n.lineno, n.args[0]))
            elif isinstance(f.value, ast.Name) and (f.value.id, f.attr) in SAVERS:
                i = SAVERS[(f.value.id, f.attr)]
                if len(n.args) > i:
                    out.append((n.lineno, n.args[i]))
    return out


def _unatomic(tree):
    """(function, line) of every write in ``tree`` whose path is not built from an atomic_path /
    atomic_dir temporary of the same function (or from a name assigned from one; by name, in the whole
    function: a search for paths given from outside, not a scope analysis)."""
    bad = []
    for func in ast.walk(tree):
        if not isinstance(func, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        safe = set()
        for w in ast.walk(func):
            for item in w.items if isinstance(w, ast.With) else ():
                c = item.context_expr
                name = (getattr(c.func, "id", None) or getattr(c.func, "attr", None)) if isinstance(c, ast.Call) else None
                if name in ATOMIC and isinstance(item.optional_vars, ast.Name):
                    safe.add(item.optional_vars.id)
        for _ in range(3):  # names built from a temporary: figdir = tmp / "figures"
            for a in ast.walk(func):
                if isinstance(a, ast.Assign) and len(a.targets) == 1 and isinstance(a.targets[0], ast.Name) \
                        and _base(a.value) in safe:
                    safe.add(a.targets[0].id)
        bad += [(func.name, line) for line, target in _writes(func) if _base(target) not in safe]
    return bad


def _unatomic_writes():
    """(module, function, line) of :func:`_unatomic` over src/qr (qr.atomic itself aside)."""
    bad = []
    for path in sorted(SRC.rglob("*.py")):
        module = ".".join(path.relative_to(SRC.parent).with_suffix("").parts).removesuffix(".__init__")
        if module != "qr.atomic":
            bad += [(module, f, line) for f, line in _unatomic(ast.parse(path.read_text()))]
    return bad


def test_the_write_search_finds_writes_outside_a_temporary():
    tree = ast.parse("def f(p, df):\n"
                     "    with atomic_path(p) as tmp:\n"
                     "        df.to_csv(tmp)\n"
                     "        d = tmp / 'x'\n"
                     "        Path(d / 'y').with_suffix('.z').write_text('a')\n"
                     "    df.to_parquet(p)\n"
                     "    with open(p, 'w') as f, lock:\n"
                     "        pass\n"
                     "    with open(p) as f:\n"
                     "        pass\n"
                     "    torch.save(df, p / 'w.pt')\n")
    assert sorted(line for line, _ in _writes(tree.body[0])) == [3, 5, 6, 7, 11]
    assert sorted(_unatomic(tree)) == [("f", 6), ("f", 7), ("f", 11)]


def test_every_file_write_goes_through_the_atomic_writer():
    """No output is ever half-written (README, 'Interrupting and resuming'): every write in src/qr is
    to a temporary of qr.atomic, but the listed ones, and the list holds no stale entry."""
    bad = _unatomic_writes()
    listed = {(m, f) for m, f, _ in bad}
    unlisted = [b for b in bad if (b[0], b[1]) not in UNATOMIC_WRITES]
    assert not unlisted, f"writes outside qr.atomic (write to atomic_path/atomic_dir's temporary): {unlisted}"
    assert listed == set(UNATOMIC_WRITES), f"no longer writing outside qr.atomic: {set(UNATOMIC_WRITES) - listed}"


# ---- one intake: the convention checks and the filter's reports read in qr.intake only (issue 35) ----------


def _intake_work(tree) -> list[tuple[str, int]]:
    """(what, line) of each convention check called and each filter report (``.nis.json``) parsed: a call of
    ``conventions.require`` or of a ``require`` imported from ``conventions``; a ``json.load(s)`` in a statement
    that names a report (``nis`` or ``report``)."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").endswith("conventions") \
                and any(a.name == "require" for a in node.names):
            found.append(("conventions.require", node.lineno))
        elif isinstance(node, ast.Attribute) and node.attr == "require" and isinstance(node.value, ast.Name) \
                and node.value.id == "conventions":
            found.append(("conventions.require", node.lineno))
    for stmt in ast.walk(tree):
        if isinstance(stmt, ast.stmt) and not isinstance(stmt, (ast.FunctionDef, ast.ClassDef, ast.With, ast.For,
                                                                 ast.If, ast.Try, ast.AsyncFunctionDef)):
            text = ast.unparse(stmt)
            if re.search(r"\bjson\.loads?\(", text) and re.search(r"nis|report", text, re.I):
                found.append(("reads a report", stmt.lineno))
    return found


def test_the_intake_search_finds_checks_and_report_reads():
    tree = ast.parse("from .conventions import require\n"
                     "def f(p, df):\n"
                     "    conventions.require(df, None, p)\n"
                     "    reports = [json.loads(Path(x).read_text()) for x in nis_files]\n"
                     "    doc = json.loads(Path(p).read_text())\n")
    assert sorted(_intake_work(tree)) == [("conventions.require", 1), ("conventions.require", 3),
                                          ("reads a report", 4)]


def test_only_the_intake_checks_conventions_and_reads_the_filters_reports():
    """A command that reads flights takes them through :mod:`qr.intake` (the convention checks, the piece
    cutting, the filter's reports read once): nothing else calls the checks or parses a ``.nis.json``."""
    bad = []
    for path in SRC.rglob("*.py"):
        module = ".".join(path.relative_to(SRC.parent).with_suffix("").parts).removesuffix(".__init__")
        if module not in ("qr.intake", "qr.conventions"):
            bad += [(module, what, line) for what, line in _intake_work(ast.parse(path.read_text()))]
    assert not bad, f"outside qr.intake (take flights through qr.intake.take, reports through read_reports): {bad}"


MAX_FUNCTION_LINES = 60


def test_no_function_is_longer_than_60_lines_but_a_compiled_kernel():
    """Every function of src/qr fits in 60 lines (docstring included), but a numba kernel (decorated ``njit`` /
    ``jit``): inside one a call to a helper is compiled in or paid per call, so its steps stay together."""
    long = []
    for path in sorted(SRC.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            size = node.end_lineno - node.lineno + 1
            kernel = any("jit" in ast.unparse(d) for d in node.decorator_list)
            if size > MAX_FUNCTION_LINES and not kernel:
                long.append(f"{path.relative_to(SRC)}:{node.lineno} {node.name} ({size} lines)")
    assert not long, long


def test_every_workflow_script_writes_its_log_through_job_log():
    """The scripts stay thin and their errors reach the user: each opens its rule's log with qr.errors.job_log
    (or hands it to a subprocess), none swaps sys.stderr by hand (the error was then printed to a closed file)."""
    scripts = sorted((ROOT / "workflow" / "scripts").glob("*.py"))
    assert len(scripts) > 20
    for p in scripts:
        text = p.read_text()
        assert "sys.stderr =" not in text, p.name
        assert "job_log(snakemake.log[0])" in text or "stderr=subprocess.STDOUT" in text, p.name
