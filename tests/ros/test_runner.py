"""Node processes stop on Ctrl-C / SIGTERM by rclpy shutting their context down, never by an exception
raised at an arbitrary line (which could strand a callback worker thread and hang the exit); a callback
that raises is logged and the node keeps running."""
import re
import subprocess
import sys
import textwrap
import threading
import time

import pytest
import rclpy
from processes import start, stop
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import SingleThreadedExecutor
from ros_testing import Inbox, call
from waiting import GENEROUS_S
from std_msgs.msg import Int32
from std_srvs.srv import Trigger

from softblock_ros.runner import spin_logging_errors

pytestmark = pytest.mark.integration

PROBE = textwrap.dedent("""
    import os, signal, sys, threading, time
    import rclpy
    from softblock_ros import runner
    # Python's handler of the signal has run (rclpy's handler passes the signal on to it): nothing more can land.
    handled = threading.Event()

    def noting(handler):
        return lambda signum, frame: (handled.set(), handler(signum, frame))
    # as in a process started from a shell: a test runner's worker may ignore SIGINT, and its children inherit that
    signal.signal(signal.SIGINT, noting(signal.default_int_handler))
    if sys.argv[2] == "init":
        runner._stop_quietly = noting(runner._stop_quietly)
        runner.init()
    else:
        rclpy.init()
    try:
        os.kill(os.getpid(), getattr(signal, sys.argv[1]))
        deadline = time.monotonic() + 60.0  # generous: only a signal never passed on takes this long
        while not (handled.is_set() and not rclpy.ok()) and time.monotonic() < deadline:
            time.sleep(0.01)  # Python code running when the signal lands: KeyboardInterrupt would hit here
    except KeyboardInterrupt:
        print("KeyboardInterrupt")
        sys.exit(3)
    print("context ok" if rclpy.ok() else "context shut down" if handled.is_set() else "signal not passed on")
""")


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"])
def test_a_stop_signal_shuts_the_context_down_without_raising(signal_name):
    probe = subprocess.run([sys.executable, "-c", PROBE, signal_name, "init"], capture_output=True, text=True,
                           timeout=120)
    assert (probe.returncode, probe.stdout.strip()) == (0, "context shut down"), probe.stderr


def test_without_init_the_same_probe_sees_keyboard_interrupt():
    """The probe can fail: plain rclpy.init lets Python raise KeyboardInterrupt on SIGINT."""
    probe = subprocess.run([sys.executable, "-c", PROBE, "SIGINT", "plain"], capture_output=True, text=True,
                           timeout=120)
    assert (probe.returncode, probe.stdout.strip()) == (3, "KeyboardInterrupt"), probe.stderr


FAILING_TIMER = textwrap.dedent("""
    from rclpy.node import Node
    from std_msgs.msg import Int32
    from softblock_ros.runner import run_node

    class EveryOtherTickFails(Node):
        def __init__(self):
            super().__init__("every_other_tick_fails")
            self.ticks = 0
            self.publisher = self.create_publisher(Int32, "ticks", 10)
            self.create_timer(0.02, self.tick)

        def tick(self):
            self.ticks += 1
            if self.ticks % 2:
                raise ValueError("theta must be finite")
            self.publisher.publish(Int32(data=self.ticks))

    raise SystemExit(run_node(EveryOtherTickFails, "every_other_tick_fails"))
""")


def test_a_failing_timer_callback_is_logged_and_the_node_keeps_running(ros_context, spin):
    client = rclpy.create_node("failing_timer_client", context=ros_context)
    ticks = Inbox(client, Int32, "ticks", 100)
    spin(client)
    node = start([sys.executable, "-c", FAILING_TIMER], stderr=subprocess.PIPE, text=True)
    try:
        ticks.wait(lambda msg: msg.data >= 20)  # ten failures later, still ticking
        assert node.poll() is None
    finally:
        code = stop(node, timeout=30.0)
    errors = node.stderr.read()
    assert code == 0, errors
    assert "a callback raised ValueError: theta must be finite (at <string>:16 in tick); the node keeps " \
           "running" in errors
    assert "Traceback" not in errors


STOPPED_WHILE_STARTING = textwrap.dedent("""
    import os, signal, sys, time
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from softblock_ros.runner import run_node

    def stop_signal():
        \"\"\"A launcher's SIGTERM lands here; returns once rclpy has shut the context down.\"\"\"
        os.kill(os.getpid(), signal.SIGTERM)
        deadline = time.monotonic() + 20.0
        while rclpy.ok() and time.monotonic() < deadline:
            time.sleep(0.01)

    class StoppedHalfWay(Node):
        def __init__(self):
            super().__init__("stopped_half_way")
            if sys.argv[1] == "node":  # after the node's first publisher, before its timer
                stop_signal()
            self.create_timer(0.1, lambda: None)  # rclpy refuses on a shut-down context

    def executor():
        if sys.argv[1] == "executor":  # the node is built, its executor not yet
            stop_signal()
        return SingleThreadedExecutor()  # rclpy refuses on a shut-down context

    raise SystemExit(run_node(StoppedHalfWay, "stopped_half_way", executor=executor))
""")


# rclpy's own noise when it refuses an executor: the half-built executor's __del__ misses an attribute (harmless).
RCLPY_HALF_BUILT_EXECUTOR = re.compile(r"Exception ignored in: <function Executor\.__del__.*?\nAttributeError: "
                                       r"'\w+' object has no attribute '_sigint_gc'\n", re.DOTALL)


@pytest.mark.parametrize("building", ["node", "executor"])
def test_a_stop_signal_while_the_node_is_being_built_is_a_clean_stop(building):
    """Seen in fresh-clone runs: the launcher stopped assembly_state right after its first (latched) message,
    inside its constructor (create_timer) or while its executor was being made (a guard condition); rclpy raised
    RCLError on the shut-down context and the node exited with status 1 and a traceback."""
    probe = subprocess.run([sys.executable, "-c", STOPPED_WHILE_STARTING, building], capture_output=True, text=True,
                           timeout=60)
    assert probe.returncode == 0, probe.stderr
    assert "Traceback" not in re.sub(RCLPY_HALF_BUILT_EXECUTOR, "", probe.stderr), probe.stderr
    assert "stopped while starting" in probe.stderr


def test_a_node_that_destroys_entities_while_it_is_spun_keeps_being_served(ros_context, spin):
    """Seen in a fresh-clone run: the HV driver's cleanup (a service callback on a worker thread) destroyed its
    publishers while the executor's thread was adding their QoS event handlers to its wait set. rclpy 7.1 raised
    InvalidHandle ("destruction was requested") from the executor's wait, which ended a plain ``spin()``: the
    driver answered no service again. Spinning as the nodes do (``spin_logging_errors``) carries on."""
    churn = rclpy.create_node("entity_churn", context=ros_context)
    listening = ReentrantCallbackGroup()  # not the service's group: its entities stay in the wait set meanwhile

    def recreate(request, response):
        # Each create and destroy wakes the executor, which then rebuilds its wait set from the node's entities.
        subscriptions = [churn.create_subscription(Int32, "churned", lambda msg: None, 10, callback_group=listening)
                         for _ in range(20)]
        for subscription in subscriptions:
            churn.destroy_subscription(subscription)
        response.success = True
        return response

    churn.create_service(Trigger, "entity_churn/recreate", recreate)
    client = rclpy.create_node("entity_churn_client", context=ros_context)
    recreate_client = client.create_client(Trigger, "entity_churn/recreate")
    spin(churn, client)
    switch_interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # threads interleave often: the race's window is a few bytecodes wide
    try:
        for _ in range(200):
            assert call(recreate_client, Trigger.Request()).success
    finally:
        sys.setswitchinterval(switch_interval)


CALLBACK_RUNNING_AT_THE_STOP = textwrap.dedent("""
    import os, signal, threading, time
    import rclpy
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node
    from softblock_ros.runner import run_node

    class BusyAtTheStop(Node):
        \"\"\"Its one timer callback is running when the stop comes, and goes on for up to 2 s.\"\"\"
        def __init__(self):
            super().__init__("busy_at_the_stop")
            self.destroyed = threading.Event()
            self.timer = self.create_timer(0.01, self.tick)

        def tick(self):
            self.timer.cancel()
            os.kill(os.getpid(), signal.SIGTERM)
            deadline = time.monotonic() + 20.0
            while rclpy.ok() and time.monotonic() < deadline:
                time.sleep(0.01)
            destroyed = self.destroyed.wait(2.0)
            print("destroyed while its callback ran" if destroyed else "callback ended first", flush=True)

        def destroy_node(self):
            self.destroyed.set()
            return super().destroy_node()

    raise SystemExit(run_node(BusyAtTheStop, "busy_at_the_stop", executor=lambda: MultiThreadedExecutor(2)))
""")


def test_a_callback_running_at_the_stop_ends_before_the_node_is_destroyed():
    """Seen in a launch smoke test of the HV driver node (a multi-threaded executor): after Ctrl-C the node was
    destroyed while a worker thread's callback still used it ("cannot use Destroyable because destruction was
    requested"), and the executor, never shut down, raised from its __del__ at exit (a traceback on stderr)."""
    probe = subprocess.run([sys.executable, "-c", CALLBACK_RUNNING_AT_THE_STOP], capture_output=True, text=True,
                           timeout=60)
    assert probe.returncode == 0, probe.stderr
    assert probe.stdout.strip() == "callback ended first", probe.stdout + probe.stderr
    assert "Traceback" not in probe.stderr, probe.stderr


def test_spin_ends_when_the_context_is_shut_down_without_a_wake():
    """rclpy's signal handling wakes the executor before it shuts the context down; when the wake comes first, spin
    sees a live context and waits again, and the shutdown itself wakes nothing (seen: about one SIGINT in ten left
    an idle node spinning until the launcher killed it). Here the context is shut down as that handling does, with
    no wake at all, while spin waits on an idle node."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("idle", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinning = threading.Thread(target=spin_logging_errors, args=(executor, node.get_logger()), daemon=True)
    spinning.start()
    try:
        time.sleep(0.5)  # lets spin reach its wait (if it has not, the test passes on any code: it cannot be flaky)
        context.handle.shutdown()  # rcl's shutdown alone: no on_shutdown callback, no wake
        spinning.join(timeout=GENEROUS_S)
        assert not spinning.is_alive(), "spin still waits on a context that was shut down"
    finally:
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        context.try_shutdown()
