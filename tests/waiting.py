"""Waiting for an event in real time (integration tests): poll until it has happened, with a deadline so generous
that it is reached only when the event never comes. A wait costs no more than the event takes; nothing here
measures how long that was."""
from __future__ import annotations

import time
from collections.abc import Callable

GENEROUS_S = 60.0  # [s] a host loaded enough to miss this has stopped running the test at all


def wait_until(predicate: Callable[[], object], what: str, timeout: float = GENEROUS_S, poll_s: float = 0.01):
    """Poll ``predicate`` until it returns something truthy and return that; past ``timeout``, fail naming
    ``what`` did not happen."""
    deadline = time.monotonic() + timeout
    while not (value := predicate()):
        assert time.monotonic() < deadline, f"no {what} within {timeout:g} s"
        time.sleep(poll_s)
    return value
