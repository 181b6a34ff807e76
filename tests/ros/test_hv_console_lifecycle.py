"""`hv_console --commands` switches the HV driver's outputs through its lifecycle (`activate`, `deactivate`), as
`ros2 lifecycle set /hv_driver activate` does where the ros2 CLI is installed: after an operator_swap step that
found a wrong block the driver stays inactive, and the wheel set-up has no ros2 CLI."""
import pytest
import rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState

from softblock_ros.hv_console import HvConsole

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def console(ros_context, spin):
    """The console beside a stand-in hv_driver lifecycle service that accepts activate once, then refuses."""
    driver = rclpy.create_node("hv_driver", context=ros_context)
    driver.transitions = []

    def change_state(request, response):
        driver.transitions.append(request.transition.id)
        response.success = driver.transitions.count(request.transition.id) == 1
        return response

    driver.create_service(ChangeState, "hv_driver/change_state", change_state)
    node = rclpy.create_node("hv_console", context=ros_context)
    console = HvConsole(node, emit=lambda record: None)
    spin(driver, node)
    return console, driver


def test_activate_and_deactivate_ask_the_drivers_lifecycle(console):
    console, driver = console
    assert console.execute("activate")["message"] == "hv_driver activated"
    assert console.execute("deactivate") == {"type": "reply", "command": "deactivate", "ok": True,
                                             "message": "hv_driver deactivated"}
    assert driver.transitions == [Transition.TRANSITION_ACTIVATE, Transition.TRANSITION_DEACTIVATE]


def test_a_refused_transition_is_one_failed_line(console):
    console, _ = console
    console.execute("activate")  # the stand-in takes the first activate (here or in the test above), no other
    reply = console.execute("activate")
    assert not reply["ok"] and reply["message"].startswith("hv_driver refused to activate")
