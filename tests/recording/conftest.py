"""Fixtures of the recording tests: a fresh rclpy context per test."""
import pytest
import rclpy
from recording_helpers import new_context


@pytest.fixture
def ros_context():
    context = new_context()
    yield context
    rclpy.try_shutdown(context=context)
