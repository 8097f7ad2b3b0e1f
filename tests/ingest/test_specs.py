"""The repository stands alone: docs/spec/ holds the contracts a user needs, equal to the shared ones.

A spec with a twin in ../shared/spec is a copy and must equal it byte for byte; the project's own specs
(contracts written here, with no shared twin: ``PROJECT_OWN``) are listed, so that a copy whose shared
twin was renamed or removed is still caught."""

import pytest

from conftest import ROOT

SHARED = ROOT.parent / "shared" / "spec"
COPIES = sorted((ROOT / "docs" / "spec").glob("*.md"))
PROJECT_OWN = {"replay.md"}  # qr replay's contract (issue 34): written in this repository


def test_the_specs_a_user_needs_are_in_docs():
    assert {p.name for p in COPIES} >= {"flight-log.md", "diagnosis.md", "evaluate.md", "hybrid.md", "export.md",
                                        "layout.md", "replay.md"}


@pytest.mark.skipif(not SHARED.is_dir(), reason="no ../shared/spec beside this checkout to compare with")
@pytest.mark.parametrize("name", sorted(p.name for p in SHARED.glob("*.md")) if SHARED.is_dir() else [])
def test_each_copy_equals_the_shared_spec(name):
    copy = ROOT / "docs" / "spec" / name
    assert copy.exists(), f"docs/spec/{name} missing: cp ../shared/spec/{name} docs/spec/"
    assert copy.read_bytes() == (SHARED / name).read_bytes(), \
        f"docs/spec/{name} differs from ../shared/spec/{name}: copy it again"


@pytest.mark.skipif(not SHARED.is_dir(), reason="no ../shared/spec beside this checkout to compare with")
def test_a_spec_without_a_shared_twin_is_one_of_the_projects_own():
    own = {p.name for p in COPIES} - {p.name for p in SHARED.glob("*.md")}
    assert own <= PROJECT_OWN, f"docs/spec/{sorted(own - PROJECT_OWN)} has no twin in ../shared/spec and is not " \
                               "listed as the project's own (PROJECT_OWN)"
    assert not PROJECT_OWN & {p.name for p in SHARED.glob("*.md")}, \
        "a spec listed as the project's own has a shared twin: compare it as a copy instead"


def test_the_projects_own_specs_are_in_the_readme():
    readme = (ROOT / "README.md").read_text()
    for name in PROJECT_OWN:
        assert f"docs/spec/{name}" in readme, f"the README's documentation table does not name docs/spec/{name}"
