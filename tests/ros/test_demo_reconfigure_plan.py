"""The reconfiguration demo's plan starts from the robot the demo built, named in the goal: the planner's own copy
of assembly/current may not have arrived yet when the goal comes (seen: "no robot given and no assembly/current
received yet" on an idle machine), or may still be the one from before the designs were loaded."""
from types import SimpleNamespace

import pytest

from planner.assembly import load_assembly
from planner.table import load_table
from softblock_config import config_file
from softblock_ros import demo_reconfigure
from softblock_ros.client import ClientError
from softblock_ros.conversions import assembly_from_msg
from softblock_ros.demo import DEMO_ASSEMBLY

pytestmark = pytest.mark.integration


def test_the_plan_goal_names_the_robot_the_demo_built(monkeypatch):
    sent = []

    def send_nothing(action, goal, **kwargs):
        sent.append(goal)
        raise ClientError("not sent")

    monkeypatch.setattr(demo_reconfigure, "run_action", send_nothing)
    built = load_assembly(config_file(DEMO_ASSEMBLY))
    with pytest.raises(ClientError, match="not sent"):
        demo_reconfigure.plan_front_pair(SimpleNamespace(plan=None), built, max_swaps=4, time_budget=5.0)
    robot, _ = assembly_from_msg(sent[0].robot, load_table())
    assert [(c.name, [b.design_id for b in c.blocks]) for c in robot.chains] == \
        [(c.name, [b.design_id for b in c.blocks]) for c in built.chains]
