"""Real-time scheduling for the HV supervisor process, where the host permits it.

SCHED_FIFO (as ros2_control's controller manager asks for) keeps the control loop running on time while other
processes load the machine; it needs root, CAP_SYS_NICE or an RLIMIT_RTPRIO at least the priority (see
docs/hv_driver.md, "Real-time priority"). Memory is locked only where the lock limit allows the whole process:
with MCL_FUTURE under a small RLIMIT_MEMLOCK, later allocations would fail.
"""
from __future__ import annotations

import ctypes
import gc
import logging
import os
import resource

log = logging.getLogger(__name__)

DEFAULT_PRIORITY = 50
MCL_CURRENT, MCL_FUTURE = 1, 2
MIN_MEMLOCK_BYTES = 1 << 30  # below this limit a Python process cannot lock all it will allocate


def _lock_memory() -> str:
    """'' when locked, else why not."""
    soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    if os.geteuid() != 0 and soft != resource.RLIM_INFINITY and soft < MIN_MEMLOCK_BYTES:  # root: CAP_IPC_LOCK
        return f"memory not locked (RLIMIT_MEMLOCK {soft} bytes)"
    libc = ctypes.CDLL("libc.so.6", use_errno=True)
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        return f"memory not locked ({os.strerror(ctypes.get_errno())})"
    return ""


def normal_priority() -> None:
    """Normal scheduling for the calling thread (e.g. in a child of a real-time process, before it runs)."""
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def fifo(priority: int) -> str:
    """SCHED_FIFO ``priority`` for the calling thread and the threads it starts from now on: '' when granted,
    else why not."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as error:
        return f"{error.strerror or error}; RLIMIT_RTPRIO {resource.getrlimit(resource.RLIMIT_RTPRIO)[0]}"
    return ""


def make_realtime(priority: int = DEFAULT_PRIORITY) -> bool:
    """Run the calling thread, and every thread it starts from now on, at SCHED_FIFO ``priority`` with memory
    locked; True when real-time. Otherwise one warning says what was refused; priority 0 asks for normal
    scheduling on purpose (also warned)."""
    gc.freeze()  # objects made during start-up stay out of the collector's scans
    if priority <= 0:
        normal_priority()  # also when started by a real-time process, whose policy children inherit
        log.warning("real-time priority switched off (realtime_priority=0): the supervisor runs at normal priority")
        return False
    refused = fifo(priority)
    if refused:
        log.warning("running at normal priority: SCHED_FIFO %d refused (%s); grant it with a realtime group and "
                    "rtprio in /etc/security/limits.conf (docs/hv_driver.md)", priority, refused)
        return False
    refused = _lock_memory()
    if refused:
        log.warning("SCHED_FIFO %d, but %s", priority, refused)
    else:
        log.info("SCHED_FIFO %d, memory locked", priority)
    return True
