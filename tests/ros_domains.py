"""Which ROS domain a test module runs in, so that parallel test workers never cross-talk.

The suite's domains (DEFAULT_TEST_DOMAINS unless SOFTBLOCK_TEST_DOMAINS says otherwise) and those that
scripts/with_env.sh gives a command started by hand without ROS_DOMAIN_ID (WRAPPER_DOMAINS) are disjoint, so
a stack started by hand never reaches a running suite.
"""

import os
import subprocess
from pathlib import Path

DEFAULT_TEST_DOMAINS = "10-99"
WRAPPER_DOMAINS = range(1, 10)  # scripts/with_env.sh: uid % 9 + 1
WRAPPER = Path(__file__).resolve().parents[1] / "scripts" / "with_env.sh"


def wrapper_domain(given: str | None = None) -> int:
    """The ROS_DOMAIN_ID a command started through scripts/with_env.sh runs in, in a process of its own, with
    ROS_DOMAIN_ID ``given`` (None: unset)."""
    environment = {name: value for name, value in os.environ.items() if name != "ROS_DOMAIN_ID"}
    environment.update({} if given is None else {"ROS_DOMAIN_ID": given})
    return int(subprocess.run([str(WRAPPER), "sh", "-c", "echo $ROS_DOMAIN_ID"], env=environment,
                              capture_output=True, text=True, check=True, timeout=60).stdout)


def domain_for(first: int, last: int, offset: int, worker: int, workers: int, module_index: int) -> int:
    """Worker ``worker`` of ``workers`` owns its own block of the domains first..last and takes the next one
    of it for each module, starting from ``offset``: two workers never share a domain, however many modules
    each runs (a worker comes back to a domain of its own only after a whole block of modules)."""
    block = (last - first + 1) // workers
    if block < 1:
        raise ValueError(f"SOFTBLOCK_TEST_DOMAINS={first}-{last}: fewer domains than the {workers} test workers")
    return first + worker * block + (offset + module_index) % block
