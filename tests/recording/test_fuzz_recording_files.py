"""Fuzzing the recordings the stack reads: MCAP files with their header, record lengths and chunk fields
overwritten at random, cut, or with chunks that inflate beyond their claim; info, recover, analyze and export
each finish with status 0 or 1 and at most one error line. (Apart from the nodes' fuzzing, test_fuzz_inputs.py,
so that the two run on different test workers.)"""
import contextlib
import io
import struct

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from crafted_mcap import TERABYTE, chunk, chunk_index_into_attachment, file_with, inflating_frame
from recording.cli import main as recording_main

pytestmark = pytest.mark.integration

FUZZ = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module")
def small_recording(tmp_path_factory):
    """The bytes of a finished recording of a few hv/state messages."""
    from rclpy.serialization import serialize_message
    from softblock_interfaces.msg import HvChannelState, HvState

    from recording.mcap_file import RecordingWriter
    path = tmp_path_factory.mktemp("mcap") / "small.mcap"
    writer = RecordingWriter(str(path))
    channel = writer.add_topic("/hv/state", "softblock_interfaces/msg/HvState")
    for i in range(3):
        writer.write(channel, serialize_message(HvState(channels=[HvChannelState(name="front", setpoint=float(i))])), i, i)
    writer.close()
    return path.read_bytes()


# rclpy prints this from a finalizer of a failed future that earlier ROS tests of this worker left behind, in
# whatever code runs when the collector frees it; the recording commands make no futures.
UNRETRIEVED_FUTURE = "The following exception was never retrieved: "


def lines_of_the_command(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if not line.startswith(UNRETRIEVED_FUTURE)]


def run_file_commands(path, folder) -> list[tuple[int, str]]:
    """(status, the command's own stderr lines) of info, recover, analyze and export of ``path``."""
    outcomes = []
    for command in (["info", str(path)], ["recover", str(path), "-o", str(folder / "fixed.mcap")],
                    ["analyze", str(path), "--out-dir", str(folder)], ["export", str(path), "--csv", str(folder)]):
        errors = io.StringIO()
        with contextlib.redirect_stderr(errors), contextlib.redirect_stdout(io.StringIO()):
            status = recording_main(command)
        event(f"{command[0]} -> {status}")
        outcomes.append((status, "\n".join(lines_of_the_command(errors.getvalue()))))
        assert status in (0, 1) and len(lines_of_the_command(errors.getvalue())) <= 1, (command, errors.getvalue())
    return outcomes


@settings(FUZZ, max_examples=40)
@given(compression=st.sampled_from(["lz4", "zstd"]), inflated=st.sampled_from([0, 9, 1000, 1 << 20]),
       claimed=st.sampled_from([0, 9, 1000, 1 << 20, TERABYTE]))
def test_any_chunk_that_inflates_beyond_its_claim_is_refused_in_one_line(tmp_path_factory, compression, inflated,
                                                                         claimed):
    """Chunks whose frames declare no size and inflate to more, as much or less than they claim."""
    folder = tmp_path_factory.mktemp("inflating")
    path = folder / "inflating.mcap"
    path.write_bytes(file_with(chunk(compression, inflating_frame(compression, inflated), claimed)))
    (_, info), (recovered, _), *_ = run_file_commands(path, folder)
    if claimed < inflated:
        assert "inflates beyond the" in info and recovered == 0


@settings(FUZZ, max_examples=40)
@given(offset=st.none() | st.integers(0, 6000))
def test_any_chunk_index_is_followed_only_to_a_checked_chunk(tmp_path_factory, offset):
    """The summary's chunk index pointed at any byte, by default at a chunk inside an attachment (claiming 2^40)."""
    from rclpy.serialization import serialize_message
    from softblock_interfaces.msg import HvChannelState, HvState

    from recording.message_definitions import full_definition
    folder = tmp_path_factory.mktemp("index")
    path = folder / "index.mcap"
    name = "softblock_interfaces/msg/HvState"
    path.write_bytes(chunk_index_into_attachment("/hv/state", name, full_definition(name), [
        serialize_message(HvState(channels=[HvChannelState(name="front", setpoint=1.0)]))], offset))
    outcomes = run_file_commands(path, folder)
    assert all("the summary's chunk index names" in errors for status, errors in outcomes if status)


@settings(FUZZ, max_examples=150)
@given(data=st.data())
def test_any_damage_to_an_mcap_file_is_read_or_refused_in_one_line(small_recording, tmp_path_factory, data):
    """Header, record lengths and chunk fields overwritten at random (a terabyte claim among them), or the
    file cut: info, recover, analyze and export each finish with status 0 or 1 and at most one error line."""
    damaged = bytearray(small_recording)
    for _ in range(data.draw(st.integers(1, 3))):
        offset = data.draw(st.integers(0, len(damaged) - 8))
        value = data.draw(st.sampled_from([0, 1, 255, 1 << 31, 1 << 40, 2**64 - 1]) | st.integers(0, 2**64 - 1))
        struct.pack_into("<Q", damaged, offset, value)
    damaged = damaged[:data.draw(st.integers(0, len(damaged)))] if data.draw(st.booleans()) else damaged
    folder = tmp_path_factory.mktemp("damaged")
    path = folder / "damaged.mcap"
    path.write_bytes(bytes(damaged))
    run_file_commands(path, folder)
