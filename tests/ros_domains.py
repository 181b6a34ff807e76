"""Which ROS domain a test module runs in, so that parallel test workers never cross-talk.

The suite's domains (DEFAULT_TEST_DOMAINS unless SOFTBLOCK_TEST_DOMAINS says otherwise) and those that
scripts/with_env.sh gives a command started by hand without ROS_DOMAIN_ID (WRAPPER_DOMAINS) are disjoint, so
a stack started by hand never reaches a running suite.
"""

DEFAULT_TEST_DOMAINS = "10-99"
WRAPPER_DOMAINS = range(1, 10)  # scripts/with_env.sh: uid % 9 + 1


def domain_for(first: int, last: int, offset: int, worker: int, workers: int, module_index: int) -> int:
    """Worker ``worker`` of ``workers`` owns its own block of the domains first..last and takes the next one
    of it for each module, starting from ``offset``: two workers never share a domain, however many modules
    each runs (a worker comes back to a domain of its own only after a whole block of modules)."""
    block = (last - first + 1) // workers
    if block < 1:
        raise ValueError(f"SOFTBLOCK_TEST_DOMAINS={first}-{last}: fewer domains than the {workers} test workers")
    return first + worker * block + (offset + module_index) % block
