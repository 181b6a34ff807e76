"""The parameter descriptors a node declares say what a string parameter allows: its choices, from the schema, in
``additional_constraints`` and in the description (what ``ros2 param describe`` prints)."""
import pytest
import rclpy

from hv_driver import DIALECTS
from softblock_ros.parameters import NODE_SCHEMAS, declare, node_schema

pytestmark = pytest.mark.integration

WITH_CHOICES = [(node, param) for node in NODE_SCHEMAS for param in node_schema(node) if param.choices]


def test_the_enumerated_parameters_are_the_ones_expected():
    assert {(node, param.name): param.choices for node, param in WITH_CHOICES} == {
        ("hv_driver", "backend"): ("sim", "serial"), ("hv_driver", "sim_link"): ("memory", "pty"),
        ("hv_driver", "dialect"): tuple(DIALECTS),
        ("recorder", "compression"): ("zstd", "lz4", "none")}


@pytest.mark.parametrize("node, param", WITH_CHOICES, ids=[f"{n}.{p.name}" for n, p in WITH_CHOICES])
def test_a_declared_string_parameter_describes_its_choices(ros_context, node, param):
    made = rclpy.create_node(f"descriptor_{node}", context=ros_context)
    try:
        declare(made, (param,))
        described = made.describe_parameter(param.name)
    finally:
        made.destroy_node()
    allowed = "one of " + ", ".join(param.choices)
    assert described.additional_constraints == allowed
    assert described.description.endswith(f"({allowed})") and described.description.startswith(param.description)
    assert described.read_only


def test_a_parameter_without_choices_has_no_constraint_text():
    (frame_id,) = [param for param in node_schema("sim_arm") if param.name == "frame_id"]
    assert frame_id.descriptor().additional_constraints == ""
