"""The demo's live view: the hint to open it names the address foxglove_bridge really serves on, and when the
bridge cannot serve (its port taken, e.g. by another demo on this machine) the demo says so and goes on without
it, rather than pointing at someone else's server."""
import io
import json
import socket
from contextlib import closing, redirect_stdout

import pytest
from websockets.sync.client import connect

from softblock_ros import demo
from softblock_ros.foxglove_bridge_node import SERVING
from softblock_ros.launcher import Stack

pytestmark = pytest.mark.integration

SUBPROTOCOL = "foxglove.sdk.v1"
TIMEOUT = 60.0  # [s] generous: the bridge starts at niceness 15 on a loaded host


def bridge_params(tmp_path, port: int):
    path = tmp_path / "params.yaml"
    path.write_text(f"foxglove_bridge:\n  ros__parameters:\n    port: {port}\n")
    return path


def run_live_view(tmp_path, port: int) -> tuple[dict, str, str]:
    """The bridge alone, started as the demo starts it; what the demo reports and says, and the stack's output."""
    output, said, report = io.StringIO(), io.StringIO(), {}
    stack = Stack(nodes=[demo.LIVE_VIEW], params=bridge_params(tmp_path, port), output=output)
    serving = stack.watch(demo.LIVE_VIEW, SERVING)
    with stack, redirect_stdout(said):
        demo.announce_live_view(stack, serving, report)
        if report["live_view"]:  # a viewer reaches it at the address the demo names
            with connect(report["live_view"], subprotocols=[SUBPROTOCOL], open_timeout=TIMEOUT) as viewer:
                assert json.loads(viewer.recv(timeout=TIMEOUT))["op"] == "serverInfo"
    return report, said.getvalue(), output.getvalue()


def test_the_demo_names_the_port_the_live_view_took(tmp_path):
    report, said, output = run_live_view(tmp_path, 0)
    assert report["live_view"].startswith("ws://127.0.0.1:") and not report["live_view"].endswith(":0"), output
    assert f"live view: open {report['live_view']} in Foxglove" in said


def test_a_taken_port_gives_no_hint_and_the_demo_goes_on(tmp_path):
    with closing(socket.socket()) as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        report, said, output = run_live_view(tmp_path, taken.getsockname()[1])
    assert report["live_view"] is None
    assert "live view: open" not in said
    assert "live view: not serving (foxglove_bridge ended with code" in said, said
    assert "cannot serve the live view on 127.0.0.1" in output


def test_the_demo_refuses_a_port_out_of_range_by_name(capsys):
    with pytest.raises(SystemExit) as exit_:
        demo.main(["--live-view-port", "70000"])
    assert exit_.value.code == 2
    assert "--live-view-port 70000: a port is 0..65535" in capsys.readouterr().err
