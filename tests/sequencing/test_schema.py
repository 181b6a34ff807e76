"""Sequence files: the shipped strategies load; every kind of mistake is rejected naming step and field;
reading is bounded (names only, size, depth, no aliases, short excerpts)."""
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from crafted_yaml import BILLION_LAUGHS, SELF_REFERENCE

from sequencing.schema import (
    Limits, MoveArmStep, ParallelStep, PulseTrainStep, RampStep, SequenceError, WaitStep, load_sequence,
    load_sequence_file, parse_sequence)

pytestmark = pytest.mark.fast

SEQUENCES = Path(__file__).resolve().parents[2] / "config" / "sequences"


def sequence_with(*steps, channels=("front", "back"), **extra):
    return {"name": "test", "channels": list(channels), "steps": list(steps), **extra}


def ramp(name="open", **fields):
    return {"name": name, "ramp": {"channel": "back", "target": 2400.0, **fields}}


def test_finger_grasp_follows_the_six_steps():
    sequence = load_sequence("finger_grasp", SEQUENCES)
    assert sequence.channels == ("front", "back")
    kinds = [type(step) for step in sequence.steps]
    assert kinds[:6] == [MoveArmStep, RampStep, MoveArmStep, RampStep, RampStep, MoveArmStep]
    open_back = sequence.steps[1]
    assert (open_back.channel, open_back.target, open_back.slew_rate) == ("back", 2400.0, 1000.0)
    assert sequence.steps[-1].target == 0.0  # ends de-energised
    assert sequence.steps[2].precondition.voltages == {"back": 2400.0}


def test_trunk_and_gait_load():
    trunk = load_sequence("trunk_flower", SEQUENCES)
    assert [step.target for step in trunk.steps if isinstance(step, RampStep)] == [2400.0, 0.0, 2400.0, 0.0]
    gait = load_sequence("legged_gait", SEQUENCES)
    walk = gait.steps[0]
    assert isinstance(walk, ParallelStep)
    trains = walk.steps
    assert all(isinstance(train, PulseTrainStep) and train.frequency == 5.0 for train in trains)
    assert [train.phase for train in trains] == [0.0, 0.5]
    assert set(trains[0].channels) | set(trains[1].channels) == set(gait.channels)
    assert walk.timeout >= trains[1].length  # default timeouts cover the whole train


def test_defaults_fill_missing_fields_and_timeouts_cover_waits():
    sequence = parse_sequence(sequence_with(
        {"name": "pause", "wait": {"duration": 2.0}},
        {"name": "go", "move_arm": {"position": [0, 0, 0.1], "orientation": [0, 0, 0, 1]}},
        defaults={"speed": 0.2, "frame_id": "world", "timeout": 5.0}))
    wait, move = sequence.steps
    assert isinstance(wait, WaitStep) and wait.timeout == 7.0
    assert (move.speed, move.frame_id, move.timeout, move.on_failure) == (0.2, "world", 5.0, "safe_stop")


@pytest.mark.parametrize("document, message", [
    (sequence_with({"name": "grab", "squeeze": {"channel": "back"}}),
     r"step 'grab' \(steps\[0\]\): kind='squeeze': unknown step kind"),
    (sequence_with(ramp(target=3000.0)),
     r"step 'open' \(steps\[0\]\): ramp.target=3000.0: above the voltage ceiling 2500 V"),
    (sequence_with({"name": "open", "ramp": {"target": 100.0}}),
     r"step 'open' \(steps\[0\]\): ramp.channel=\(missing\): a channel declared"),
    (sequence_with({"name": "open", "ramp": {"channel": "middle", "target": 100.0}}),
     r"ramp.channel='middle': a channel declared in `channels` \['front', 'back'\]"),
    (sequence_with({"name": "pause", "wait": {"duration": -1.0}}),
     r"step 'pause' \(steps\[0\]\): wait.duration=-1.0: must be >= 0"),
    (sequence_with(ramp(target=-5.0)), r"ramp.target=-5.0: must be >= 0"),
    (sequence_with(ramp(duration=2.0, slew_rate=100.0)), r"ramp.duration=2.0: give either slew_rate or duration"),
    (sequence_with(ramp(), ramp()), r"step 'open' \(steps\): name='open': used twice"),
    (sequence_with(ramp(), {"name": "both", "wait": {"duration": 1}, "ramp": {}}),
     r"step 'both' \(steps\[1\]\): kind=\['wait', 'ramp'\]: exactly one step kind"),
    (sequence_with({**ramp(), "on_failure": "ignore"}), r"on_failure='ignore': one of \['safe_stop', 'estop'\]"),
    (sequence_with({"name": "pause", "wait": {"duration": 5.0}, "timeout": 1.0}),
     r"timeout=1.0: shorter than the step itself"),
    (sequence_with({**ramp(), "precondition": {"voltages": {"back": 9000}}}),
     r"precondition.voltages.back=9000: above the voltage ceiling"),
    (sequence_with({"name": "go", "move_arm": {"position": [0, 0], "orientation": [0, 0, 0, 1]}}),
     r"step 'go' \(steps\[0\]\): move_arm.position=\[0, 0\]: a list of 3 finite numbers"),
    (sequence_with({"name": "go", "move_arm": {"position": [0, 0, 0], "orientation": [0, 0, 0, 2]}}),
     r"move_arm.orientation=\[0.0, 0.0, 0.0, 2.0\]: a unit quaternion"),
    (sequence_with({"name": "outer", "parallel": [ramp("inner", target=1e4)]}),
     r"step 'inner' \(steps\[0\].parallel\[0\]\): ramp.target=10000.0: above the voltage ceiling"),
    (sequence_with(ramp(), channels=[]), r"channels=\[\]: a non-empty list"),
    (sequence_with(), r"steps=\[\]: a non-empty list of steps"),
    ({"name": "test", "channels": ["a"], "steps": [], "extra": 1}, r"unknown key\(s\) \['extra'\]"),
])
def test_invalid_sequences_name_the_step_and_field(document, message):
    with pytest.raises(SequenceError, match=message):
        parse_sequence(document)


def pulse(**fields):
    spec = {"channels": ["front"], "voltage": 2000.0, "frequency": 5.0, "duty": 0.5, "cycles": 3,
            "slew_rate": 50000.0, **fields}
    return sequence_with({"name": "gait", "pulse_train": spec})


@pytest.mark.parametrize("fields, message", [
    ({"frequency": 8.0}, r"pulse_train.frequency=8.0: must be <= 5"),
    ({"slew_rate": 20000.0}, r"pulse_train.slew_rate=20000.0: too slow: an edge takes 188 ms .* is 100 ms"),
    ({"duty": 0.9}, r"pulse_train.slew_rate=50000.0: too slow: an edge takes 75 ms .* is 20 ms"),
    ({"cycles": 0}, r"pulse_train.cycles=0: an integer >= 1"),
    ({"cycles": 2.5}, r"pulse_train.cycles=2.5: an integer >= 1"),
    ({"channels": []}, r"pulse_train.channels=\[\]: a non-empty list"),
    ({"slew_rate": 0.0}, r"pulse_train.slew_rate=0: must be > 0"),
    ({"edge": "sine"}, r"pulse_train.edge='sine': one of smooth, square"),
    ({"phase": 1.0}, r"pulse_train.phase=1.0: must be <= 0.999"),
])
def test_pulse_trains_must_fit_the_frequency_and_slew_limit(fields, message):
    with pytest.raises(SequenceError, match=message):
        parse_sequence(pulse(**fields))


def test_limits_are_options():
    relaxed = Limits(voltage_ceiling_v=5000.0, max_pulse_frequency_hz=10.0)
    parse_sequence(sequence_with(ramp(target=3000.0)), relaxed)
    with pytest.raises(SequenceError, match=r"ramp.slew_rate=2000.0: above the HV driver's slew limit 1000"):
        parse_sequence(sequence_with(ramp(slew_rate=2000.0)), Limits(max_slew_rate_v_per_s=1000.0))


def test_unknown_name_lists_the_known_sequences(tmp_path):
    with pytest.raises(SequenceError, match=r"sequence='grasp_all': no such file .*\['finger_grasp', 'legged_gait'"):
        load_sequence("grasp_all", SEQUENCES)
    with pytest.raises(SequenceError, match=r"sequence='': give a sequence name"):
        load_sequence("", SEQUENCES)


def test_invalid_yaml_names_line_and_column_without_quoting_the_file(tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: x\nsteps: [\n  - {name: a\n")
    with pytest.raises(SequenceError, match=r"broken.yaml: invalid YAML: line 3, column 3: expected the node") as error:
        load_sequence("broken", tmp_path)
    assert "name: a" not in str(error.value)
    valid = tmp_path / "custom.yaml"
    valid.write_text(yaml.safe_dump(sequence_with(ramp())))
    assert load_sequence("custom", tmp_path).name == "test"
    assert load_sequence_file(valid).source == str(valid)


LOAD_WITH_MEMORY_LIMIT = """
import resource, sys
from sequencing.schema import SequenceError, load_sequence
resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))  # a loader that expands the document fails fast
try:
    load_sequence("crafted", sys.argv[1])
except SequenceError as error:
    print(error)
"""


@pytest.mark.parametrize("text", [BILLION_LAUGHS, SELF_REFERENCE], ids=["billion_laughs", "self_reference"])
def test_anchors_and_aliases_are_refused_in_one_short_line(tmp_path, text):
    """In a child process with bounded memory and time: expanding a billion laughs would take gigabytes."""
    (tmp_path / "crafted.yaml").write_text(text)
    run = subprocess.run([sys.executable, "-c", LOAD_WITH_MEMORY_LIMIT, str(tmp_path)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 0, run.stderr[-1000:]
    assert re.fullmatch(r".*crafted.yaml: invalid YAML: line 1, column \d+: anchors and aliases \(&name, \*name\) "
                        r"are not allowed; write the value out\n", run.stdout)
    assert len(run.stdout) < 300


def test_deep_nesting_and_large_files_are_refused_before_parsing(tmp_path):
    (tmp_path / "deep.yaml").write_text("[" * 5000 + "]" * 5000)
    with pytest.raises(SequenceError, match=r"deep.yaml: invalid YAML: line 1, column 33: nested deeper than 32"):
        load_sequence("deep", tmp_path)
    (tmp_path / "large.yaml").write_text("# padding\n" * 100_000)
    with pytest.raises(SequenceError, match=r"large.yaml: larger than 262144 bytes"):
        load_sequence("large", tmp_path)


def test_values_quoted_in_errors_are_cut_short():
    document = sequence_with(ramp(channel="x" * 100_000))
    with pytest.raises(SequenceError, match=r"ramp.channel='x+\.\.\.x+': a channel declared") as error:
        parse_sequence(document)
    assert len(str(error.value)) < 300
    looped: list = []
    looped.append(looped)
    with pytest.raises(SequenceError, match=r"steps\[0\]: step=\[\[\[.*: a mapping"):
        parse_sequence(sequence_with(looped))


@pytest.mark.parametrize("goal", ["/etc/passwd", "../sequences/finger_grasp", "finger_grasp.yaml", "~/x", "a/b",
                                  "x" * 101, "finger grasp", "\0"])
def test_goals_are_names_never_paths(goal):
    with pytest.raises(SequenceError, match=r"a sequence name is up to 100 letters, digits, '_' or '-' \(no paths\)"):
        load_sequence(goal, SEQUENCES)


def test_a_link_out_of_the_sequence_directory_is_refused(tmp_path):
    outside = tmp_path / "outside.yaml"
    outside.write_text(yaml.safe_dump(sequence_with(ramp())))
    directory = tmp_path / "sequences"
    directory.mkdir()
    (directory / "escape.yaml").symlink_to(outside)
    (directory / "passwd.yaml").symlink_to("/etc/passwd")
    for name in ("escape", "passwd"):
        with pytest.raises(SequenceError, match=rf"sequence='{name}': .*{name}.yaml links outside .*; refused$"):
            load_sequence(name, directory)
    (directory / "inside.yaml").symlink_to(directory / "escape.yaml")
    with pytest.raises(SequenceError, match="links outside"):
        load_sequence("inside", directory)


def test_a_file_that_is_not_a_sequence_is_refused_without_its_contents(tmp_path):
    (tmp_path / "notes.yaml").write_text("root:x:0:0:root:/root:/bin/bash\n" * 50)
    with pytest.raises(SequenceError, match=r"notes.yaml: a sequence file is a mapping \(name, channels, steps\), "
                                            r"not a str$") as error:
        load_sequence("notes", tmp_path)
    assert "/bin/bash" not in str(error.value)
