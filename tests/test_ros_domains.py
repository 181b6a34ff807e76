"""Parallel test workers never share a ROS domain, whatever the range and however many modules each runs
(a shared domain let one worker's fuzz test e-stop another worker's HV driver in a fresh-clone run)."""
import itertools
import os

import pytest
from ros_domains import DEFAULT_TEST_DOMAINS, WRAPPER_DOMAINS, domain_for, wrapper_domain

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


def test_the_env_wrappers_default_domain_is_outside_the_suites_default_range():
    """A stack started by hand through scripts/with_env.sh without ROS_DOMAIN_ID must not join a running suite
    (the old default, $$ % 100 + 1, fell inside 10-99 for 90 pids in 100)."""
    first, last = (int(bound) for bound in DEFAULT_TEST_DOMAINS.split("-"))
    assert wrapper_domain() in WRAPPER_DOMAINS
    assert not set(WRAPPER_DOMAINS) & set(range(first, last + 1))


def test_every_command_of_one_user_gets_the_same_default_domain():
    """Two terminals of one user meet: the launcher in one and run_sequence in the other, both without
    ROS_DOMAIN_ID (a default taken from the process id put them in different domains, and run_sequence found no
    sequencer). Each run is another process."""
    assert {wrapper_domain() for _ in range(6)} == {os.getuid() % 9 + 1}
