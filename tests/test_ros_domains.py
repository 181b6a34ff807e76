"""Parallel test workers never share a ROS domain, whatever the range and however many modules each runs
(a shared domain let one worker's fuzz test e-stop another worker's HV driver in a fresh-clone run)."""
import itertools

import pytest
from ros_domains import domain_for

pytestmark = pytest.mark.fast


@pytest.mark.parametrize("first, last", [(10, 99), (160, 220), (100, 160), (0, 232), (5, 7)])
@pytest.mark.parametrize("workers", [1, 2, 3])
def test_workers_never_share_a_domain_and_stay_in_the_range(first, last, workers):
    for offset in (0, 7, 2**200 + 3):
        used = [{domain_for(first, last, offset, w, workers, m) for m in range(120)} for w in range(workers)]
        for mine, theirs in itertools.combinations(used, 2):
            assert not mine & theirs
        assert all(first <= domain <= last for domains in used for domain in domains)


def test_a_range_smaller_than_the_workers_is_refused_by_name():
    with pytest.raises(ValueError, match="SOFTBLOCK_TEST_DOMAINS=10-11: fewer domains than the 3 test workers"):
        domain_for(10, 11, 0, 0, 3, 0)
