"""The supervisor's channel refuses what is not a bounded request, and its server answers only the supply's public
calls; errors cross the channel as their own classes."""
import json
import logging
import os
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from hv_driver import ControlError, HvError, LimitError, ipc, realtime
from hv_driver.ipc import MAX_WAIT_S
from hv_driver.server import _NOTHING_WAITING, SupervisorServer

pytestmark = pytest.mark.fast


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
        self.waited, self.beats, self.lost = [], [], []

    def listen(self, take_in):
        self.take_in = take_in

    def heartbeat(self, token, sent=None):
        self.beats.append((token, sent))

    def node_lost(self, reason):
        self.lost.append(reason)

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


@pytest.mark.parametrize("method", ["__init__", "_change", "open", "node_lost", "listen", "_supervisor", 7, None])
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


def test_what_waited_in_the_channel_is_taken_in_in_order_with_its_sending_stamps(server):
    """A stall of the supervisor: three seconds of the node's keep-alives and heartbeats wait unread in the channel.
    Taken in afterwards, each counts from its sending stamp, and nothing is judged while messages still wait."""
    node, connection = ipc.socket_pair()
    connection.setblocking(False)
    stamps = time.monotonic() - 3.0 + 0.1 * np.arange(30)
    with node, connection, ThreadPoolExecutor(1) as pool:
        for k, sent in enumerate(stamps):
            ipc.send(node, {"method": ipc.KEEPALIVE, "sent": sent} if k % 2 else
                           {"id": k, "method": "heartbeat", "args": ["token"], "sent": sent})
        server._connection = connection
        with server._taken:
            taken = [server._take_in(connection, pool) for _ in stamps]
            assert server._take_in(connection, pool) is _NOTHING_WAITING
    assert taken == [None] * len(stamps)
    assert server.supply.beats == [("token", pytest.approx(sent)) for sent in stamps[::2]]
    assert server._last_keepalive == pytest.approx(stamps[-1]) and server._taken_up_to == pytest.approx(stamps[-1])


def test_a_stamp_that_is_not_a_time_is_refused_by_a_reply_naming_it(server):
    node, connection = ipc.socket_pair()
    connection.setblocking(False)
    with node, connection, ThreadPoolExecutor(1) as pool:
        ipc.send(node, {"id": 5, "method": "heartbeat", "args": ["token"], "sent": "yesterday"})
        with server._taken:
            assert server._take_in(connection, pool) is None
        pool.shutdown(wait=True)
        reply = ipc.receive(node)
    assert reply["id"] == 5 and "sent='yesterday'" in reply["error"]["message"] and server.supply.beats == []


def test_a_reader_that_takes_nothing_in_does_not_hold_the_loop(server):
    """Messages wait, but no thread reads them: the loop's wait ends after its patience (and it judges)."""
    node, connection = ipc.socket_pair()
    with node, connection:
        ipc.send(node, {"method": ipc.KEEPALIVE, "sent": time.monotonic()})
        server._connection = connection
        server._wait_taken_in(0.01)  # returns; nothing asserted about how long it took
        server._connection = None
        server._wait_taken_in(0.01)  # no node: nothing to wait for


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
