"""A recorder process killed with SIGKILL leaves a readable prefix that `recover` makes valid;
SIGINT and SIGTERM finish the file cleanly."""
import json
import signal
import struct
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import rclpy
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader
from recording_helpers import hv_state, read_decoded, stamp, wait_for, write_recording
from rosbags.highlevel import AnyReader
from softblock_interfaces.msg import HvState

from recording import mcap_file
from recording.mcap_file import describe, recover
from softblock_ros.recording.cli import main

pytestmark = pytest.mark.integration


def start_recorder(path: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "softblock_ros.recording", "record", "-o", str(path),
         "--flush-period", "0.2", "--discovery-period", "0.2", "/hv/state"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def readable_prefix(path: Path) -> int:
    """Messages a plain streaming reader gets out of a file that may be unfinished."""
    count = 0
    try:
        with open(path, "rb") as stream:
            for _ in NonSeekingReader(stream).iter_messages(log_time_order=False):
                count += 1
    except (McapError, struct.error, ValueError):
        pass  # the unfinished tail
    return count


class HvPublisher:
    """Publishes HvState with measured_voltage = 0, 1, 2, ... from its own rclpy context."""

    def __init__(self, ros_context):
        self.node = rclpy.create_node("hv_driver", context=ros_context)
        # deep history: a recorder stalled by a loaded machine still gets every sample
        self.publisher = self.node.create_publisher(HvState, "hv/state", 1000)
        self.sent = 0

    def wait_for_recorder(self):
        wait_for(lambda: self.publisher.get_subscription_count() >= 1, "recorder subscription")

    def publish(self, count: int):
        for _ in range(count):
            self.publisher.publish(stamp(self.node, hv_state({"front": self.sent})))
            self.sent += 1

    def publish_until(self, stop: threading.Event):
        while not stop.wait(0.005):
            self.publish(2)


def test_sigkill_leaves_readable_prefix_and_recover_makes_it_valid(ros_context, tmp_path):
    path = tmp_path / "killed.mcap"
    recorder = start_recorder(path)
    hv = HvPublisher(ros_context)
    stop = threading.Event()
    try:
        hv.wait_for_recorder()
        feeder = threading.Thread(target=hv.publish_until, args=(stop,))
        feeder.start()
        wait_for(lambda: readable_prefix(path) >= 100, "flushed chunks on disk")
        recorder.send_signal(signal.SIGKILL)
        recorder.wait()
    finally:
        stop.set()
        recorder.kill()
    feeder.join()
    prefix = readable_prefix(path)
    with pytest.raises(McapError, match="recover"):
        describe(str(path))

    result = recover(str(path), str(tmp_path / "recovered.mcap"))

    assert result.success and result.messages == prefix and result.topics == {"/hv/state": prefix}
    info = describe(str(tmp_path / "recovered.mcap"))
    assert info["topics"]["/hv/state"]["count"] == prefix
    voltages = [m.channels[0].measured_voltage
                for _, m, _, _ in read_decoded(str(tmp_path / "recovered.mcap"))["/hv/state"]]
    assert voltages == [float(i) for i in range(prefix)]  # a gap-free prefix of what was sent
    with AnyReader([tmp_path / "recovered.mcap"]) as reader:
        assert sum(1 for _ in reader.messages()) == prefix


def test_info_describes_a_finished_file_and_points_unfinished_ones_to_recover(tmp_path, capsys):
    finished = write_recording(str(tmp_path / "ok.mcap"), [
        ("/hv/state", hv_state({"front": 1.0}), 1), ("/hv/state", hv_state({"front": 2.0}), 2)])
    assert main(["info", finished]) == 0
    assert "/hv/state  softblock_interfaces/msg/HvState  2 messages  volatile" in \
        capsys.readouterr().out
    assert main(["info", finished, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["topics"]["/hv/state"] == {
        "type": "softblock_interfaces/msg/HvState", "count": 2, "durability": ["volatile"]}
    unfinished = tmp_path / "cut.mcap"
    unfinished.write_bytes(Path(finished).read_bytes()[:-200])
    assert main(["info", str(unfinished)]) == 1
    assert "recover" in capsys.readouterr().err


@pytest.mark.parametrize("stop_signal", [signal.SIGINT, signal.SIGTERM])
def test_sigint_and_sigterm_finish_the_file(ros_context, tmp_path, stop_signal):
    path = tmp_path / "stopped.mcap"
    recorder = start_recorder(path)
    hv = HvPublisher(ros_context)
    try:
        hv.wait_for_recorder()
        hv.publish(50)
        wait_for(lambda: readable_prefix(path) == 50, "all messages flushed")
        recorder.send_signal(stop_signal)
        _, errors = recorder.communicate(timeout=30)
    finally:
        recorder.kill()
    assert recorder.returncode == 0, errors
    assert "wrote 50 messages on 1 topics" in errors
    assert describe(str(path))["topics"]["/hv/state"]["count"] == 50


def test_recover_refuses_a_file_that_is_not_mcap(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    result = recover(str(junk), str(tmp_path / "out.mcap"))
    assert not result.success and "MCAP header" in result.message
    assert not (tmp_path / "out.mcap").exists()


@pytest.fixture
def crashed(tmp_path):
    """A recording cut as a SIGKILL leaves it: no summary, no footer."""
    finished = write_recording(str(tmp_path / "whole.mcap"), [
        ("/hv/state", hv_state({"front": float(i)}), i) for i in range(1, 4)])
    path = tmp_path / "crashed.mcap"
    path.write_bytes(Path(finished).read_bytes()[:-200])
    return path


@pytest.mark.parametrize("alias", ["symlink", "hardlink", "dotted path"])
def test_recover_onto_another_name_of_the_source_refuses_and_keeps_it(crashed, alias, capsys):
    before = crashed.read_bytes()
    target = crashed.parent / "target.mcap"
    if alias == "symlink":
        target.symlink_to(crashed)
    elif alias == "hardlink":
        target.hardlink_to(crashed)
    else:
        target = crashed.parent / "." / crashed.name
    assert main(["recover", str(crashed), "-o", str(target)]) == 1
    assert "is the recording" in capsys.readouterr().err
    assert crashed.read_bytes() == before


def test_recover_replaces_an_existing_target_only_when_done(crashed, tmp_path, monkeypatch):
    target = tmp_path / "out.mcap"
    target.write_bytes(b"previous output")
    readable_records = mcap_file._readable_records

    def failing_records(path):  # the disk fills up after a few records
        yield from list(readable_records(path))[:3]
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(mcap_file, "_readable_records", failing_records)
    with pytest.raises(OSError, match="No space left"):
        recover(str(crashed), str(target), overwrite=True)
    assert target.read_bytes() == b"previous output"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["crashed.mcap", "out.mcap", "whole.mcap"]


@pytest.mark.parametrize("through_link", [False, True])
def test_recover_refuses_an_existing_output_unless_overwrite_and_never_writes_through_a_link(crashed, tmp_path,
                                                                                            capsys, through_link):
    """Old: `recover -o EXISTING` silently replaced the existing file."""
    precious = tmp_path / "precious.mcap"
    precious.write_bytes(b"a recording worth keeping")
    target = tmp_path / "link.mcap" if through_link else precious
    if through_link:
        target.symlink_to(precious)
    assert main(["recover", str(crashed), "-o", str(target)]) == 1
    assert capsys.readouterr().err == (f"error: {target} exists; choose another output, or overwrite it on purpose "
                                       "(--overwrite)\n")
    assert precious.read_bytes() == b"a recording worth keeping" and target.is_symlink() == through_link
    assert main(["recover", str(crashed), "-o", str(target), "--overwrite"]) == 0
    assert "recovered 3 messages" in capsys.readouterr().out
    assert not target.is_symlink() and target.read_bytes().startswith(b"\x89MCAP")
    if through_link:
        assert precious.read_bytes() == b"a recording worth keeping"  # the link was replaced, not its target


def test_a_target_that_appears_during_recovery_is_kept(crashed, tmp_path, monkeypatch):
    target = tmp_path / "out.mcap"
    readable_records = mcap_file._readable_records

    def another_writer_meanwhile(path):
        yield from readable_records(path)
        target.write_bytes(b"written meanwhile")

    monkeypatch.setattr(mcap_file, "_readable_records", another_writer_meanwhile)
    with pytest.raises(FileExistsError):
        recover(str(crashed), str(target))
    assert target.read_bytes() == b"written meanwhile"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["crashed.mcap", "out.mcap", "whole.mcap"]
