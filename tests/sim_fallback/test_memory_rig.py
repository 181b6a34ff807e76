"""The simulated supplies inside the driver's process (`MemoryRig`, the default link of the simulated backend):
every command is answered within the write, on the real clock, with no thread of the simulation to schedule; faults
reach the device and channel named, and a bad address is refused naming it."""
import threading

import pytest

from sim_fallback.memory_port import MemoryPort
from sim_fallback.memory_rig import MemoryRig

pytestmark = pytest.mark.fast


def query(port: MemoryPort, line: bytes) -> bytes:
    port.write(line + b"\r\n")
    return port.read(port.in_waiting)  # all there is: the answer came within the write


def test_on_the_real_clock_a_command_is_answered_within_its_write_by_no_other_thread():
    rig = MemoryRig(channels=2, dialect="iseg-edcp", devices=2)
    threads = threading.active_count()
    echo_and_answer = query(rig.ports[0], b"*IDN?")
    assert echo_and_answer.startswith(b"*IDN?\r\n") and b"iseg" in echo_and_answer.lower()
    assert threading.active_count() == threads  # nothing started, nothing to deschedule
    assert [port.name for port in rig.ports] == ["memory:iseg-edcp/0", "memory:iseg-edcp/1"]


def test_a_fault_reaches_only_the_device_and_channel_it_names_and_clear_ends_it():
    rig = MemoryRig(channels=2, dialect="iseg-edcp", devices=2)
    rig.inject("no_reply", channel=None, device=1)
    assert query(rig.ports[0], b"*IDN?") != b"" and query(rig.ports[1], b"*IDN?") == b""
    rig.clear_faults()
    assert query(rig.ports[1], b"*IDN?") != b""


@pytest.mark.parametrize("fault, channel, device, named", [
    ("short", None, None, "fault='short'"), ("over_current", 4, None, "channel=4"),
    ("over_current", 0, 2, "device=2"), ("over_current", "0", None, "channel='0'")])
def test_a_bad_fault_channel_or_device_is_refused_naming_it(fault, channel, device, named):
    rig = MemoryRig(channels=2, dialect="iseg-edcp", devices=2)
    with pytest.raises(ValueError, match=named.replace("(", r"\(")):
        rig.inject(fault, channel, device)
    assert query(rig.ports[0], b"*IDN?") != b""  # the rig is unharmed


def test_single_channel_dialects_have_one_channel_per_device_whatever_is_asked():
    assert MemoryRig(channels=4, dialect="keithley-2290", devices=2).channels == 1
    with pytest.raises(ValueError, match="dialect='hvx'"):
        MemoryRig(dialect="hvx")
