"""Two hosts on one machine for tests and benchmarks: network namespaces joined by a link emulated in user
space (delay, jitter, loss, partition), since the kernel's netem is not available everywhere."""
from .emulated import EmulatedHosts, LabError
from .hosts import Host, HostsError, unavailable_reason
from .link import Conditions, Link

__all__ = ["Conditions", "EmulatedHosts", "Host", "HostsError", "LabError", "Link", "unavailable_reason"]
