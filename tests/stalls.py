"""Stalls of the test's own process, as a garbage collection or a loaded host makes them."""
import sys
import time


def stall_this_process(seconds: float) -> float:
    """Keep every Python thread of this process from running for at least ``seconds``: the caller holds the
    interpreter, and no waiting thread asks it back for longer than that. Returns the stall's length."""
    switch_interval = sys.getswitchinterval()
    began = time.monotonic()
    sys.setswitchinterval(seconds)
    try:
        while time.monotonic() - began < seconds:
            pass
    finally:
        sys.setswitchinterval(switch_interval)
    return time.monotonic() - began
