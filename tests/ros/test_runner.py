"""Node processes stop on Ctrl-C / SIGTERM by rclpy shutting their context down, never by an exception
raised at an arbitrary line (which could strand a callback worker thread and hang the exit)."""
import subprocess
import sys
import textwrap

import pytest

PROBE = textwrap.dedent("""
    import os, signal, sys, time
    import rclpy
    from softblock_ros.runner import init
    init()
    try:
        os.kill(os.getpid(), getattr(signal, sys.argv[1]))
        deadline = time.monotonic() + 20.0
        while rclpy.ok() and time.monotonic() < deadline:
            time.sleep(0.01)  # Python code running when the signal lands: KeyboardInterrupt would hit here
    except KeyboardInterrupt:
        print("KeyboardInterrupt")
        sys.exit(3)
    print("context ok" if rclpy.ok() else "context shut down")
""")


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"])
def test_a_stop_signal_shuts_the_context_down_without_raising(signal_name):
    probe = subprocess.run([sys.executable, "-c", PROBE, signal_name], capture_output=True, text=True,
                           timeout=60)
    assert (probe.returncode, probe.stdout.strip()) == (0, "context shut down"), probe.stderr


def test_without_init_the_same_probe_sees_keyboard_interrupt():
    """The probe can fail: plain rclpy.init lets Python raise KeyboardInterrupt on SIGINT."""
    plain = PROBE.replace("from softblock_ros.runner import init\ninit()", "rclpy.init()")
    probe = subprocess.run([sys.executable, "-c", plain, "SIGINT"], capture_output=True, text=True, timeout=60)
    assert (probe.returncode, probe.stdout.strip()) == (3, "KeyboardInterrupt"), probe.stderr
