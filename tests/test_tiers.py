"""Every test of the suite is in exactly one tier (pyproject.toml's markers), so `make test`, which runs the tiers
one after the other, runs every test once, and `make test-fast` runs the fast tier alone: a test without a tier
would run in none. Checked over every test the run collected (tests/conftest.py records them before `-m`
deselects any); `make test` and `make test-fast` collect the whole suite."""
import subprocess
import sys
import tomllib
from collections import Counter
from pathlib import Path

import pytest
from hypothesis import settings

pytestmark = pytest.mark.fast

TESTS = Path(__file__).resolve().parent
MARKERS = tomllib.loads((TESTS.parent / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["markers"]
TIERS = ("fast", "integration", "stack")


def test_the_tiers_are_the_registered_markers():
    assert [marker.split(":")[0] for marker in MARKERS] == list(TIERS)


def test_every_collected_test_has_exactly_one_tier(collected_tiers):
    wrong = {node: tiers for node, tiers in collected_tiers.items() if len(tiers) != 1}
    assert wrong == {}, f"{len(wrong)} tests without exactly one of the tiers {TIERS}: {dict(list(wrong.items())[:20])}"
    print(f"tests per tier: {dict(Counter(tiers[0] for tiers in collected_tiers.values()))}")


@pytest.fixture(scope="module")
def whole_suite_collected(collected_tiers) -> bool:
    """Whether this run collected every test module of the suite; if not, the checks on the whole suite's
    collection run once in a run that does (a pytest process over the suite, these checks only)."""
    suite = {str(path.relative_to(TESTS.parent)) for path in TESTS.rglob("test_*.py")}
    if suite <= {node.split("::")[0] for node in collected_tiers}:
        return True
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-k", "test_no_tier_is_empty",
                          str(TESTS)], cwd=TESTS.parent, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    return False


@pytest.mark.parametrize("tier", TIERS)
def test_no_tier_is_empty(tier, collected_tiers, whole_suite_collected):
    """`pytest -m <tier>` with nothing to run exits 5, which would fail `make test`: the tier has tests among those
    pytest collects from the whole suite."""
    if whole_suite_collected:
        assert any(tier in tiers for tiers in collected_tiers.values())


def test_hypothesis_examples_have_no_wall_clock_deadline():
    """No test asserts a wall-clock duration, hypothesis' per-example deadline included (tests/conftest.py)."""
    assert settings().deadline is None
