"""Recording files from anywhere: a record claiming 2^40 bytes, bad QoS metadata or a FIFO is one line and exit
status 1 for info, recover and analyze; the recorder never truncates an existing file or writes through a
link; export writes one CSV per topic; /rosout is recorded."""
import csv
import os
import re
import struct
import subprocess
import sys

import pytest
import rclpy
from crafted_mcap import chunk, chunk_index_into_attachment, file_with, inflating_frame
from mcap.opcode import Opcode
from mcap.writer import Writer
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from recording_helpers import Spinner, hv_state, read_decoded, stamp, wait_for, write_recording

from recording.analysis import HV_STATE
from recording.bounded_mcap import MAX_CHUNK_BYTES
from recording.cli import main
from recording.message_definitions import full_definition
from softblock_ros.recording.recorder_node import RecorderNode

pytestmark = pytest.mark.integration

START = 1_700_000_000_000_000_000
STEP = 10_000_000


@pytest.fixture
def recording(tmp_path):
    entries = [("/hv/state", stamp(START + i * STEP, hv_state({"front": 100.0 * i, "back": -1.0})), START + i * STEP)
               for i in range(5)]
    return write_recording(str(tmp_path / "grasp.mcap"), entries)


def chunk_offset(data: bytes) -> int:
    """Offset of the first top-level chunk record."""
    position = 8
    while data[position] != Opcode.CHUNK:
        position += 9 + struct.unpack_from("<Q", data, position + 1)[0]
    return position


def with_claim(path, field: str, tmp_path, cut: bool = False) -> str:
    """A copy of `path` whose first chunk claims 2^40 bytes: as its record length or its uncompressed size;
    `cut` drops what follows the chunk (a killed recorder's file)."""
    data = bytearray(open(path, "rb").read())
    chunk = chunk_offset(data)
    length = struct.unpack_from("<Q", data, chunk + 1)[0]
    struct.pack_into("<Q", data, chunk + 1 if field == "length" else chunk + 9 + 16, 1 << 40)
    crafted = tmp_path / f"{field}{'-cut' if cut else ''}.mcap"
    crafted.write_bytes(bytes(data[:chunk + 9 + length]) if cut else bytes(data))
    return str(crafted)


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("command", ["info", "analyze", "export"])
@pytest.mark.parametrize("field", ["length", "uncompressed_size"])
def test_a_chunk_claiming_a_terabyte_is_refused_in_one_line(recording, tmp_path, capsys, command, field):
    crafted = with_claim(recording, field, tmp_path)
    extra = ["--csv", str(tmp_path / "csv")] if command == "export" else ["--out-dir", str(tmp_path)] * (
        command == "analyze")
    assert main([command, crafted, *extra]) == 1
    claimed = "claims 1099511627776 bytes" + (" uncompressed" if field == "uncompressed_size" else "")
    assert claimed in one_line_error(capsys)


@pytest.mark.parametrize("field", ["length", "uncompressed_size"])
def test_recover_keeps_what_comes_before_a_chunk_claiming_a_terabyte(recording, tmp_path, capsys, field):
    crafted = with_claim(recording, field, tmp_path, cut=True)
    assert main(["recover", crafted, "-o", str(tmp_path / "fixed.mcap")]) == 0
    out = capsys.readouterr().out
    assert re.search(r"recovered 0 messages into .*fixed.mcap \(stopped at what follows: chunk at byte \d+ claims "
                     r"1099511627776 bytes|a record at byte \d+ claims 1099511627776 bytes", out), out
    assert main(["info", str(tmp_path / "fixed.mcap")]) == 0


def test_a_zstd_frame_claiming_more_than_the_limit_is_refused(tmp_path, capsys):
    """The chunk's own claim is small; the zstd frame header inside claims more (zstd trusts the frame)."""
    import zstandard
    path = tmp_path / "frame.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start("ros2", "test")
        writer.finish()
    data = bytearray(path.read_bytes())
    frame = zstandard.ZstdCompressor().compress(b"\0" * 16)
    # zstd frame header: magic, descriptor with an 8-byte content size, window, then the size itself
    fake = b"\x28\xb5\x2f\xfd" + bytes([0xC0]) + b"\x50" + struct.pack("<Q", MAX_CHUNK_BYTES + 1) + frame[-6:]
    records = fake
    content = struct.pack("<QQQI", 0, 0, 16, 0) + struct.pack("<I", 4) + b"zstd" + struct.pack("<Q", len(records))
    chunk = bytes([Opcode.CHUNK]) + struct.pack("<Q", len(content) + len(records)) + content + records
    header_end = 8 + 9 + struct.unpack_from("<Q", data, 9)[0]
    path.write_bytes(bytes(data[:header_end]) + chunk + bytes(data[header_end:]))
    assert main(["recover", str(path), "-o", str(tmp_path / "fixed.mcap")]) == 0
    assert f"claims {MAX_CHUNK_BYTES + 1} bytes uncompressed, above the limit" in capsys.readouterr().out


def nested_chunk_file(tmp_path) -> str:
    path = tmp_path / "nested.mcap"
    path.write_bytes(chunk_index_into_attachment("/hv/state", HV_STATE, full_definition(HV_STATE), [
        serialize_message(hv_state({"front": float(i)})) for i in range(3)]))
    return str(path)


@pytest.mark.parametrize("command", ["info", "analyze", "export"])
def test_a_chunk_index_pointing_into_an_attachment_is_refused_in_one_line(tmp_path, capsys, command):
    """Old: the seeking reader followed the summary's chunk index to a chunk inside an attachment, which claims a
    terabyte: analyze and export ended in a MemoryError traceback (zstd), info described the file."""
    extra = {"analyze": ["--out-dir", str(tmp_path)], "export": ["--csv", str(tmp_path / "csv")]}.get(command, [])
    assert main([command, nested_chunk_file(tmp_path), *extra]) == 1
    assert re.fullmatch(r"error: .*nested.mcap: the summary's chunk index names a chunk of \d+ bytes at byte \d+; "
                        r"the file has none there\n", one_line_error(capsys))


def test_play_refuses_a_chunk_index_pointing_into_an_attachment_in_one_line(tmp_path):
    result = subprocess.run([sys.executable, "-m", "softblock_ros.recording", "play", nested_chunk_file(tmp_path)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1 and re.fullmatch(r"error: .*the file has none there\n", result.stderr), result.stderr


MEMORY_LIMIT = 512 << 20  # [bytes] of address space: the commands need at most half of it (analyze ~240 MB)


def bounded_command(*argv) -> subprocess.CompletedProcess:
    """A recording command in a child whose address space is limited to MEMORY_LIMIT."""
    code = (f"import resource, sys; resource.setrlimit(resource.RLIMIT_AS, ({MEMORY_LIMIT}, {MEMORY_LIMIT})); "
            "from recording.cli import main; sys.exit(main(sys.argv[1:]))")
    return subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("compression", ["lz4", "zstd"])
def test_a_chunk_that_inflates_beyond_its_claim_is_refused_within_bounded_memory(tmp_path, compression):
    """Old: an lz4 chunk claiming 16 bytes whose frame (declaring no size) inflates to 1 GiB, a 4.4 MB file, held
    recover for more than 30 s at 2 GB; under a 512 MiB limit it ends in a MemoryError traceback. A zstd one ended
    recover with an error instead of keeping what comes before it."""
    path = tmp_path / "bomb.mcap"
    path.write_bytes(file_with(chunk(compression, inflating_frame(compression, 1 << 30), 16)))
    refusal = r"chunk at byte \d+ inflates beyond the 16 bytes it declares"
    fixed = tmp_path / "fixed.mcap"
    result = bounded_command("recover", str(path), "-o", str(fixed))
    assert result.returncode == 0 and result.stderr == "", result.stderr[-2000:]
    assert re.fullmatch(rf"recovered 0 messages into {fixed} \(stopped at what follows: {refusal}\)\n", result.stdout)
    for command in (["info"], ["analyze", "--out-dir", str(tmp_path)], ["export", "--csv", str(tmp_path / "csv")]):
        result = bounded_command(command[0], str(path), *command[1:])
        assert result.returncode == 1 and re.fullmatch(rf"error: {path}: {refusal}\n", result.stderr), \
            result.stderr[-2000:]


def test_recover_and_info_refuse_a_fifo_without_blocking(tmp_path, capsys):
    fifo = tmp_path / "live.mcap"
    os.mkfifo(fifo)
    for command in (["recover", str(fifo), "-o", str(tmp_path / "out.mcap")], ["info", str(fifo)]):
        assert main(command) == 1
        assert "live.mcap: not a regular file" in one_line_error(capsys)


@pytest.mark.parametrize("qos", ["a: *nowhere", "- [unclosed", "just text", "- durability: [a, b]\n"])
def test_info_and_analyze_with_bad_qos_metadata_say_so_in_one_line(tmp_path, capsys, qos):
    path = str(tmp_path / "qos.mcap")
    with open(path, "wb") as stream:  # as another program might write it
        writer = Writer(stream)
        writer.start("ros2", "elsewhere")
        schema = writer.register_schema(HV_STATE, "ros2msg", full_definition(HV_STATE).encode())
        channel = writer.register_channel("/hv/state", "cdr", schema, {"offered_qos_profiles": qos})
        writer.add_message(channel, START, serialize_message(hv_state({"front": 1.0})), START)
        writer.finish()
    for command in (["info", path], ["analyze", path, "--out-dir", str(tmp_path)]):
        code = main(command)
        if qos.startswith("- durability"):
            assert code == 0  # a list of maps: its odd values are shown as they are
            capsys.readouterr()
            continue
        assert code == 1
        assert "offered_qos_profiles of /hv/state" in one_line_error(capsys)


def test_export_writes_one_csv_per_topic_with_flat_si_columns(recording, tmp_path, capsys):
    directory = tmp_path / "csv"
    assert main(["export", recording, "--csv", str(directory)]) == 0
    assert "/hv/state: 5 rows" in capsys.readouterr().out
    with open(directory / "hv.state.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    assert len(rows) == 5
    assert [float(row["time_s"]) for row in rows] == pytest.approx([0.0, 0.01, 0.02, 0.03, 0.04])
    assert int(rows[1]["log_time_ns"]) == START + STEP
    assert float(rows[1]["header.stamp"]) == pytest.approx((START + STEP) / 1e9)
    assert rows[1]["channels.0.name"] == "front" and float(rows[1]["channels.0.measured_voltage"]) == 100.0
    assert float(rows[3]["channels.1.measured_voltage"]) == -1.0
    # exporting again replaces the files
    assert main(["export", recording, "--csv", str(directory)]) == 0


def test_export_of_an_image_gives_the_length_of_its_pixel_data(tmp_path):
    from sensor_msgs.msg import Image
    path = write_recording(str(tmp_path / "image.mcap"), [("/camera/silhouette", Image(
        height=100, width=100, encoding="mono8", step=100, data=bytes(10_000)), START)])
    assert main(["export", path, "--csv", str(tmp_path)]) == 0
    with open(tmp_path / "camera.silhouette.csv", newline="") as stream:
        (row,) = list(csv.DictReader(stream))
    assert row["data.length"] == "10000" and row["width"] == "100" and "data.0" not in row


@pytest.mark.parametrize("through_link", [False, True])
def test_the_recorder_refuses_an_existing_output_and_never_writes_through_a_link(ros_context, tmp_path,
                                                                                 through_link):
    """Old: `record -o EXISTING` truncated the file in place (39,422 -> 789 bytes), through a link its target."""
    old = tmp_path / "old.mcap"
    old.write_bytes(b"a recording worth keeping" * 100)
    output = tmp_path / "link.mcap" if through_link else old
    if through_link:
        output.symlink_to(old)
    with pytest.raises(FileExistsError, match=r"link.mcap exists|old.mcap exists"):
        RecorderNode(str(output), context=ros_context)
    assert old.read_bytes() == b"a recording worth keeping" * 100
    node = RecorderNode(context=ros_context, parameter_overrides=[
        Parameter("output", value=str(output)), Parameter("overwrite", value=True)])
    node.destroy_node()
    if through_link:
        assert old.read_bytes() == b"a recording worth keeping" * 100  # the link was replaced, not its target
    assert not output.is_symlink() and output.read_bytes().startswith(b"\x89MCAP")


def test_the_cli_refuses_an_existing_output_in_one_line(tmp_path):
    old = tmp_path / "old.mcap"
    old.write_bytes(b"keep")
    result = subprocess.run([sys.executable, "-m", "softblock_ros.recording", "record", "-o", str(old)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1 and old.read_bytes() == b"keep"
    assert "old.mcap exists; choose another output, or overwrite it on purpose (--overwrite" in result.stderr
    assert "Traceback" not in result.stderr


TALKER = """
import time, rclpy
rclpy.init()
node = rclpy.create_node("hv_driver")
while True:
    node.get_logger().error("FAULT over_current on front")
    time.sleep(0.1)
"""


def test_rosout_is_recorded_so_fault_logs_end_up_in_the_file(ros_context, tmp_path):
    """Old: /rosout was excluded by default, so an HV fault logged by the driver was not in the recording."""
    path = tmp_path / "logs.mcap"
    recorder = RecorderNode(str(path), context=ros_context, parameter_overrides=[
        Parameter("discovery_period_s", value=0.1)])
    spinner = Spinner(ros_context, recorder)
    talker = subprocess.Popen([sys.executable, "-c", TALKER], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        # the recorder logs a few lines of its own; the talker one every 0.1 s
        wait_for(lambda: recorder.writer.message_counts.get("/rosout", 0) >= 20, "the talker's log lines recorded")
    finally:
        talker.kill()
        talker.wait()
        spinner.close()
        recorder.destroy_node()
    logs = read_decoded(str(path))["/rosout"]
    assert any(log.name == "hv_driver" and log.msg == "FAULT over_current on front" for _, log, _, _ in logs)
