"""The repository stands alone: docs/spec/ holds the contracts a user needs, equal to the shared ones."""

import pytest

from conftest import ROOT

SHARED = ROOT.parent / "shared" / "spec"
COPIES = sorted((ROOT / "docs" / "spec").glob("*.md"))


def test_the_specs_a_user_needs_are_in_docs():
    assert {p.name for p in COPIES} >= {"flight-log.md", "diagnosis.md", "evaluate.md", "hybrid.md"}


@pytest.mark.skipif(not SHARED.is_dir(), reason="no ../shared/spec beside this checkout to compare with")
@pytest.mark.parametrize("name", sorted(p.name for p in SHARED.glob("*.md")) if SHARED.is_dir() else [])
def test_each_copy_equals_the_shared_spec(name):
    copy = ROOT / "docs" / "spec" / name
    assert copy.exists(), f"docs/spec/{name} missing: cp ../shared/spec/{name} docs/spec/"
    assert copy.read_bytes() == (SHARED / name).read_bytes(), \
        f"docs/spec/{name} differs from ../shared/spec/{name}: copy it again"
