"""The supervisor's channel refuses what is not a bounded request, and its server answers only the supply's public
calls; errors cross the channel as their own classes."""
import json
import logging
import os

import pytest

from hv_driver import ControlError, HvError, LimitError, ipc, realtime
from hv_driver.ipc import MAX_WAIT_S
from hv_driver.server import SupervisorServer


def test_messages_over_the_bound_or_not_json_objects_are_refused():
    left, right = ipc.socket_pair()
    with left, right:
        with pytest.raises(ValueError, match="at most"):
            ipc.send(left, {"pad": "x" * ipc.MAX_MESSAGE_BYTES})
        left.send(b"[1, 2]")
        with pytest.raises(ValueError, match="not an object"):
            ipc.receive(right)
        left.send(b"{not json")
        with pytest.raises(ValueError):
            ipc.receive(right)
        left.close()
        with pytest.raises(ipc.ChannelClosed):
            ipc.receive(right)


@pytest.mark.parametrize("error", [LimitError("target 9 kV exceeds the hard maximum"), ControlError("held by 'a'"),
                                   ValueError("edge=7")])
def test_errors_cross_the_channel_as_their_own_class(error):
    reply = json.loads(json.dumps(ipc.error_reply(3, error)))
    with pytest.raises(type(error), match=str(error)):
        ipc.raise_remote_error(reply["error"])


def test_an_unknown_error_class_arrives_as_an_hv_error():
    with pytest.raises(HvError, match="boom"):
        ipc.raise_remote_error({"type": "SystemExit", "message": "boom"})


class FakeSupply:
    device_id = "fake"

    def __init__(self):
        self.waited = []

    def snapshot(self):
        return {"ok": True}

    def wait_outputs_off(self, timeout=None):
        self.waited.append(timeout)
        return True


@pytest.fixture
def server():
    path = f"/tmp/hv-ipc-{os.getpid()}.sock"
    server = SupervisorServer(FakeSupply(), path, "digest")
    yield server
    server._listener.close()
    os.unlink(path)


@pytest.mark.parametrize("method", ["__init__", "_change", "open", "node_lost", "_supervisor", 7, None])
def test_only_the_supplys_public_calls_are_served(server, method):
    with pytest.raises(ValueError, match="unknown"):
        server._call({"method": method})


def test_a_wait_is_bounded_and_a_handle_must_exist(server):
    server._call({"method": "wait_outputs_off", "kwargs": {"timeout": 1e9}})
    server._call({"method": "wait_outputs_off", "kwargs": {"timeout": None}})
    assert server.supply.waited == [MAX_WAIT_S, MAX_WAIT_S]
    with pytest.raises(ValueError, match="a number of seconds"):
        server._call({"method": "wait_outputs_off", "kwargs": {"timeout": "soon"}})
    with pytest.raises(ValueError, match="unknown"):
        server._call({"method": "handle", "args": [12, "done"]})
    with pytest.raises(ValueError, match="args must be a list"):
        server._call({"method": "snapshot", "args": "x"})
    assert server._call({"method": "hello"})["digest"] == "digest"


def test_realtime_refused_is_one_warning_naming_how_to_grant_it(monkeypatch, caplog):
    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with caplog.at_level(logging.WARNING, logger="hv_driver.realtime"):
        assert realtime.make_realtime(50) is False
    assert len(caplog.records) == 1 and "limits.conf" in caplog.text and "normal priority" in caplog.text


def test_realtime_switched_off_on_purpose_is_warned(caplog):
    with caplog.at_level(logging.WARNING, logger="hv_driver.realtime"):
        assert realtime.make_realtime(0) is False
    assert "switched off" in caplog.text
