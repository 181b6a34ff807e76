"""The operator_swap step: schema validation, and the engine with a fake robot, operator and camera on an
injected clock (confirmation, timeout, a mismatch naming the block, a match)."""
import threading

import pytest
from fake_robot import FakeOperator, FakeRobot, TickingClock
from softblock_config import config_file

from planner.assembly import Chain, PlacedBlock, load_assembly
from planner.reconfigure import swap_steps
from sequencing.engine import SequenceEngine
from sequencing.reconfiguration import operator_swap_step
from sequencing.ports import AssemblyVerdict, ChannelReading, RunOptions
from sequencing.schema import OperatorSwapStep, SequenceError, Swap, parse_sequence

pytestmark = pytest.mark.fast

FAST = RunOptions(poll_period_s=0.001, settle_time_s=0.0, safe_stop_timeout_s=0.5)
SWAP = {"chain": "front_left", "position": 2, "remove": 57, "insert": 15, "rotation_steps": 0}
MATCH = AssemblyVerdict("asymmetric_gripper", "front_left", True, "as built")
OLD = AssemblyVerdict("strawberry_gripper", "front_left", False, "assembly mistakes found",
                      ("block 3: design 15 instead of 57 (candidates [15])",))
WRONG = AssemblyVerdict("asymmetric_gripper", "front_left", False, "assembly mistakes found",
                        ("block 3: design 57 instead of 15 (candidates [57, 12])",))


def document(swap_spec=None, timeout=None, after_ramp=True):
    step = {"name": "swap", "operator_swap": swap_spec or {"assembly": "asymmetric_gripper", "swaps": [SWAP]}}
    if timeout is not None:
        step["timeout"] = timeout
    steps = [step] + ([{"name": "close", "ramp": {"channel": "front", "target": 2000}}] if after_ramp else [])
    return {"name": "reconfigure", "channels": ["front", "back"], "steps": steps}


def run(robot, sequence=None, cancel=None, clock=None):
    engine = SequenceEngine(robot, FAST, clock=clock or TickingClock(1e-3))
    return engine.run(sequence or parse_sequence(document()), cancel)


def test_the_step_holds_the_expected_swaps_and_prompts_with_them():
    step = parse_sequence(document()).steps[0]
    assert step == OperatorSwapStep(name="swap", assembly="asymmetric_gripper", timeout=600.0,
                                    swaps=(Swap("front_left", 2, 57, 15, 0),))
    assert step.prompt() == ("build assembly 'asymmetric_gripper': finger front_left, position 2: "
                             "remove design 57, insert design 15 at rotation step 0")


@pytest.mark.parametrize("spec, field, problem", [
    ({"swaps": [SWAP]}, "operator_swap.assembly=(missing)", "the name of the assembly"),
    ({"assembly": "a", "swaps": {"chain": "x"}}, "operator_swap.swaps=", "a list of swaps"),
    ({"assembly": "a", "swaps": [{**SWAP, "position": -1}]}, "operator_swap.swaps[0].position=-1", ">= 0"),
    ({"assembly": "a", "swaps": [{**SWAP, "insert": 0}]}, "operator_swap.swaps[0].insert=0", ">= 1 or null"),
    ({"assembly": "a", "swaps": [{**SWAP, "rotation_steps": 12}]}, "operator_swap.swaps[0].rotation_steps=12",
     "between 0 and 11"),
    ({"assembly": "a", "swaps": [{**SWAP, "remove": None, "insert": None}]}, "operator_swap.swaps[0].insert",
     "give remove, insert or both"),
    ({"assembly": "a", "swaps": [SWAP, SWAP]}, "operator_swap.swaps[1].position=2", "swapped twice"),
    ({"assembly": "a", "swaps": [{**SWAP, "block": 3}]}, "operator_swap.swaps[0]=", "unknown key(s) ['block']"),
    ({"assembly": "a", "confirm": True}, "operator_swap=", "unknown key(s) ['confirm']"),
])
def test_bad_fields_are_named(spec, field, problem):
    with pytest.raises(SequenceError, match=r"step 'swap' \(steps\[0\]\)") as error:
        parse_sequence(document(spec))
    assert field in str(error.value) and problem in str(error.value)


def test_a_swap_cannot_run_beside_other_steps_or_expect_a_live_channel():
    parallel = {"name": "both", "parallel": [{"name": "swap", "operator_swap": {"assembly": "a"}},
                                             {"name": "w", "wait": {"duration": 1}}]}
    with pytest.raises(SequenceError, match=r"parallel\[0\]\.operator_swap='swap': not allowed in a parallel"):
        parse_sequence({"name": "x", "channels": ["front"], "steps": [parallel]})
    live = {"name": "swap", "operator_swap": {"assembly": "a"}, "precondition": {"voltages": {"front": 1000}}}
    with pytest.raises(SequenceError, match=r"precondition.voltages.front=1000.0: an operator_swap needs every "
                                            r"channel at 0 V"):
        parse_sequence({"name": "x", "channels": ["front"], "steps": [live]})


def test_a_match_after_the_confirmation_lets_the_sequence_energise_again():
    robot = FakeRobot(["front", "back"])
    robot.operator = FakeOperator(confirm_at=3, verdicts=(MATCH,))
    result = run(robot)
    assert result.success, result.message
    assert robot.calls[:2] == [("hv_outputs", False), ("request_operator", parse_sequence(document()).steps[0].prompt())]
    assert robot.operator.closed and robot.operator.polls >= 3
    assert [call[1:3] for call in robot.ramps()] == [("front", 2000.0)]


def test_the_operator_is_told_once_the_request_is_open_and_the_outputs_are_off():
    """A program acting as the operator confirms on `awaiting_operator`: by then the request must take it."""
    robot = FakeRobot(["front", "back"])
    robot.operator = FakeOperator(confirm_at=1, verdicts=(MATCH,))
    seen = []

    def on_event(event):
        if event.phase == "awaiting_operator":
            seen.append((event.name, event.message, list(robot.calls), robot.operator.polls))

    engine = SequenceEngine(robot, FAST, on_event=on_event, clock=TickingClock(1e-3))
    assert engine.run(parse_sequence(document())).success
    prompt = parse_sequence(document()).steps[0].prompt()
    assert seen == [("swap", prompt, [("hv_outputs", False), ("request_operator", prompt)], 0)]


def test_a_verdict_on_the_old_assembly_is_waited_past():
    robot = FakeRobot(["front", "back"])
    robot.operator = FakeOperator(confirm_at=1, verdicts=(None, OLD, OLD, MATCH))
    assert run(robot).success


def test_a_mismatch_names_the_block_and_no_channel_is_energised():
    robot = FakeRobot(["front", "back"])
    robot.operator = FakeOperator(confirm_at=2, verdicts=(WRONG,))
    result = run(robot)
    assert not result.success and result.failed_step == "swap"
    assert "assembly 'asymmetric_gripper' not as built: chain front_left: block 3: design 57 instead of 15" \
        in result.message
    assert robot.ramps() == [] and robot.operator.closed


def test_no_confirmation_times_out_on_the_injected_clock():
    robot = FakeRobot(["front", "back"])
    result = run(robot, parse_sequence(document(timeout=5)), clock=TickingClock(1.0))
    assert not result.success
    assert "timed out after 5 s waiting for the operator's confirmation" in result.message
    assert robot.ramps() == [] and robot.operator.closed


def test_no_verdict_on_the_new_assembly_times_out_naming_the_last_one():
    robot = FakeRobot(["front", "back"])
    robot.operator = FakeOperator(confirm_at=1, verdicts=(OLD,))
    result = run(robot, parse_sequence(document(timeout=5)), clock=TickingClock(1.0))
    assert "waiting for the estimator's verdict on assembly 'asymmetric_gripper'; last verdict: assembly " \
           "mistakes found on assembly 'strawberry_gripper'" in result.message
    assert robot.ramps() == []


def test_a_live_channel_keeps_the_operator_away():
    robot = FakeRobot(["front", "back"])
    robot.states["back"] = ChannelReading(1500.0, output_enabled=True)
    result = run(robot)
    assert "precondition: channel 'back' energised (1500 V); an operator swap needs every channel at 0 V" \
        in result.message
    assert not [call for call in robot.calls if call[0] == "request_operator"]


def test_a_channel_energised_during_the_swap_fails_it_and_is_ramped_down():
    robot = FakeRobot(["front", "back"])

    class EnergisedMidway(FakeOperator):
        def confirmed(self):
            if self.polls == 2:
                robot.states["front"] = ChannelReading(800.0, output_enabled=True)
            return super().confirmed()

    robot.operator = EnergisedMidway(confirm_at=None)
    result = run(robot)
    assert "channel 'front' energised (800 V) during the operator's swap" in result.message
    assert [call[1:3] for call in robot.ramps()] == [("front", 0.0)]  # the safe stop


def test_a_cancel_while_waiting_closes_the_request():
    robot = FakeRobot(["front", "back"])
    cancel = threading.Event()

    class CancelMidway(FakeOperator):
        def confirmed(self):
            if self.polls == 3:
                cancel.set()
            return super().confirmed()

    robot.operator = CancelMidway(confirm_at=None)
    result = run(robot, cancel=cancel)
    assert result.canceled and robot.operator.closed and robot.ramps() == []


def test_a_plans_swap_steps_become_one_operator_swap_step():
    built = load_assembly(config_file("assemblies/gripper.yaml"))
    finger = built.chains[0]
    old = finger.blocks[1]
    changed = finger.blocks[:1] + (PlacedBlock(old.design_id % 84 + 1, 3),) + finger.blocks[2:]
    target = built.with_chains(*[Chain(finger.name, finger.hv_channel, changed, finger.base_position,
                                      finger.base_orientation), *built.chains[1:]])
    steps = swap_steps(built, target, {old.design_id % 84 + 1: 1})
    spec = operator_swap_step("rebuild", "next_gripper", steps, timeout_s=900)
    step = parse_sequence({"name": "r", "channels": ["front"], "steps": [spec]}).steps[0]
    assert step.timeout == 900 and step.assembly == "next_gripper"
    assert step.swaps == (Swap(finger.name, 1, old.design_id, old.design_id % 84 + 1, 3),)


def outputs_on_at_0_v(robot) -> None:
    """As the HV driver node when active: every output on, at 0 V."""
    for name in robot.states:
        robot.states[name] = ChannelReading(0.0, output_enabled=True)


def test_outputs_on_at_0_v_are_switched_off_for_the_swap_and_on_again_once_verified():
    robot = FakeRobot(["front", "back"])
    outputs_on_at_0_v(robot)
    seen_during_swap = []

    class Watching(FakeOperator):
        def confirmed(self):
            seen_during_swap.append({n: s.output_enabled for n, s in robot.states.items()})
            return super().confirmed()

    robot.operator = Watching(confirm_at=2, verdicts=(MATCH,))
    result = run(robot)
    assert result.success, result.message
    names = [call[0] for call in robot.calls]
    assert names[:2] == ["hv_outputs", "request_operator"] and robot.calls[0] == ("hv_outputs", False)
    assert seen_during_swap and all(not any(seen.values()) for seen in seen_during_swap)
    assert ("hv_outputs", True) in robot.calls
    assert names.index("ramp") > robot.calls.index(("hv_outputs", True))


def test_after_a_mistake_the_outputs_stay_off():
    robot = FakeRobot(["front", "back"])
    outputs_on_at_0_v(robot)
    robot.operator = FakeOperator(confirm_at=1, verdicts=(WRONG,))
    result = run(robot)
    assert not result.success and "the HV outputs stay off until a swap is verified" in result.message
    assert [call for call in robot.calls if call[0] == "hv_outputs"] == [("hv_outputs", False)]
    assert not any(state.output_enabled for state in robot.states.values()) and robot.ramps() == []


def test_outputs_that_cannot_be_switched_off_keep_the_operator_away():
    robot = FakeRobot(["front", "back"])
    outputs_on_at_0_v(robot)
    robot.refuse_outputs = "hv_driver/change_state: service not available"
    result = run(robot)
    assert not result.success and result.failed_step == "swap"
    assert ("the HV outputs could not be switched off for the swap: hv_driver/change_state: service not "
            "available") in result.message
    assert not [call for call in robot.calls if call[0] == "request_operator"]
