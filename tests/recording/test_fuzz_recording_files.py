"""Fuzzing the recordings the stack reads: MCAP files with their header, record lengths and chunk fields
overwritten at random, cut, or with chunks that inflate beyond their claim; info, recover, analyze and export
each finish with status 0 or 1 and at most one error line. (Apart from the nodes' fuzzing, test_fuzz_inputs.py,
so that the two run on different test workers.)"""
import contextlib
import io
import struct

import pytest
from hypothesis import HealthCheck, assume, event, given, settings
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


def run_command(command: list[str]) -> tuple[int, str]:
    """(status, its own stderr lines) of one recording command; it must end with status 0 or 1 and at most one
    error line."""
    errors = io.StringIO()
    with contextlib.redirect_stderr(errors), contextlib.redirect_stdout(io.StringIO()):
        status = recording_main(command)
    event(f"{command[0]} -> {status}")
    lines = lines_of_the_command(errors.getvalue())
    assert status in (0, 1) and len(lines) <= 1, (command, errors.getvalue())
    return status, "\n".join(lines)


def run_file_commands(path, folder) -> list[tuple[int, str]]:
    """run_command of info, recover, analyze (the summary, without its plot) and export of ``path``."""
    return [run_command(command) for command in (
        ["info", str(path)], ["recover", str(path), "-o", str(folder / "fixed.mcap")],
        ["analyze", str(path), "--out-dir", str(folder), "--no-plot"], ["export", str(path), "--csv", str(folder)])]


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


def damaged_copy(data, recording: bytes) -> bytes:
    """``recording`` with 1-3 of its 8-byte words overwritten at random (a terabyte claim among them), perhaps
    cut."""
    damaged = bytearray(recording)
    for _ in range(data.draw(st.integers(1, 3))):
        offset = data.draw(st.integers(0, len(damaged) - 8))
        value = data.draw(st.sampled_from([0, 1, 255, 1 << 31, 1 << 40, 2**64 - 1]) | st.integers(0, 2**64 - 1))
        struct.pack_into("<Q", damaged, offset, value)
    return bytes(damaged[:data.draw(st.integers(0, len(damaged)))] if data.draw(st.booleans()) else damaged)


# The summary of each damaged file here, the plot of fewer below: drawing a readable file's plot takes about 0.3 s,
# most of the time of a run that plotted all 150, and how many stay readable differs from seed to seed.
@settings(FUZZ, max_examples=150)
@given(data=st.data())
def test_any_damage_to_an_mcap_file_is_read_or_refused_in_one_line(small_recording, tmp_path_factory, data):
    """Header, record lengths and chunk fields overwritten at random, or the file cut: info, recover, analyze
    (summary) and export each finish with status 0 or 1 and at most one error line."""
    folder = tmp_path_factory.mktemp("damaged")
    path = folder / "damaged.mcap"
    path.write_bytes(damaged_copy(data, small_recording))
    run_file_commands(path, folder)


@settings(FUZZ, max_examples=20, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(data=st.data())
def test_any_damaged_file_that_is_read_is_also_plotted(small_recording, tmp_path_factory, data):
    """Damaged files that analyze reads: its plot, drawn from whatever values the damage left, finishes too."""
    folder = tmp_path_factory.mktemp("damaged_read")
    path = folder / "damaged.mcap"
    path.write_bytes(damaged_copy(data, small_recording))
    analyze = ["analyze", str(path), "--out-dir", str(folder)]
    assume(run_command([*analyze, "--no-plot"])[0] == 0)
    status, errors = run_command(analyze)
    assert status == 0 and (folder / "damaged.png").stat().st_size > 0, errors
