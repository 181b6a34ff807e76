"""Lost samples from the publishers' sample counters: gaps, a restarted publisher, interleaving publishers."""
import pytest

from recording.gaps import checkable, find_gaps

pytestmark = pytest.mark.fast


def numbered(*sequences):
    return [(sequence, 1000 * sequence) for sequence in sequences]


def test_a_gap_is_reported_with_the_numbers_and_times_around_it():
    found = find_gaps(numbered(1, 2, 3, 7, 8))
    assert found["received"] == 5 and found["lost"] == 3 and not found["interleaved"]
    assert found["gaps"] == [{"after": 3, "before": 7, "lost": 3, "after_time_ns": 3000, "before_time_ns": 7000}]


def test_a_restarted_publisher_starts_a_new_run():
    found = find_gaps(numbered(5, 6, 7, 1, 2, 4))
    assert found["lost"] == 1 and not found["interleaved"]


def test_a_second_publisher_that_joined_later_makes_the_numbers_unusable():
    found = find_gaps(numbered(1, 2, 40, 3, 41, 4))
    assert found["interleaved"]


def test_only_one_reliable_publisher_is_checkable():
    assert checkable("- {reliability: reliable}") == ""
    assert "best-effort" in checkable("- {reliability: best_effort}")
    assert "2 publishers" in checkable("- {reliability: reliable}\n- {reliability: reliable}")
