"""Publishers send from a Fast DDS thread of their own (asynchronous publication) unless the environment chose
another mode, and the HV driver says so when it runs in another.

In Fast DDS's default, synchronous mode the publishing thread sends, and rclpy holds the interpreter lock through
publish(): a reader that stopped answering held publish() for up to 1 s, and every thread of the publishing process
with it (the HV driver's control loop; a fresh-clone demo lost the driver for 1.2 s). The measurement is
benchmarks/publish_hold.py."""
import os
import subprocess
import sys

import pytest
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter

from softblock_ros import PUBLICATION_MODE_VARIABLE
from softblock_ros.hv_driver_node import HvDriverNode

pytestmark = pytest.mark.integration

PROBE = f"import os, softblock_ros; print(os.environ[{PUBLICATION_MODE_VARIABLE!r}])"


def mode_after_import(**environment) -> str:
    base = {key: value for key, value in os.environ.items() if key != PUBLICATION_MODE_VARIABLE}
    probe = subprocess.run([sys.executable, "-c", PROBE], env={**base, **environment}, capture_output=True,
                           text=True, timeout=60)
    assert probe.returncode == 0, probe.stderr
    return probe.stdout.strip()


def test_importing_the_package_chooses_asynchronous_publication():
    assert mode_after_import() == "ASYNCHRONOUS"


def test_a_mode_the_environment_chose_is_kept():
    assert mode_after_import(**{PUBLICATION_MODE_VARIABLE: "SYNCHRONOUS"}) == "SYNCHRONOUS"


def test_the_driver_warns_when_publication_is_synchronous(ros_context, spin, monkeypatch, capfd):
    monkeypatch.setenv(PUBLICATION_MODE_VARIABLE, "SYNCHRONOUS")
    driver = HvDriverNode(context=ros_context, parameter_overrides=[Parameter("autostart", value=False)])
    spin(driver)
    try:
        assert driver.trigger_configure() == TransitionCallbackReturn.SUCCESS
    finally:
        driver.trigger_shutdown()
    logged = capfd.readouterr().err
    assert f"{PUBLICATION_MODE_VARIABLE}=SYNCHRONOUS: a reader that stops answering can block" in logged, logged
