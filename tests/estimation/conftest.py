"""Shared fixture of the estimation tests: the look-up table."""
import pytest

from planner.table import load_table


@pytest.fixture(scope="session")
def table():
    return load_table()
