"""The analysis imports and runs where ROS is not installed (README: "Analysis needs no ROS"): no rclpy, no
ament_index_python; writing a recording, which looks message definitions up in the ament index, says what it
lacks."""
import json
import subprocess
import sys

from recording_helpers import hv_state, stamp, write_recording

from recording.analysis import analyze

START = 1_700_000_000_000_000_000
WITHOUT_ROS = ("import sys; sys.modules.update(dict.fromkeys(['rclpy', 'ament_index_python', "
               "'ament_index_python.packages']))\n")  # None in sys.modules: any import of them fails


def run_without_ros(code: str, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", WITHOUT_ROS + code], capture_output=True, text=True, timeout=120,
                          cwd=cwd)


def test_the_analysis_imports_and_analyses_without_ament_index_python_or_rclpy(tmp_path):
    path = str(tmp_path / "grasp.mcap")
    write_recording(path, [("/hv/state", stamp(START + i * 100_000_000, hv_state({"front": 500.0 * i})),
                            START + i * 100_000_000) for i in range(5)])
    result = run_without_ros("import json\nimport recording.analysis, recording.cli, recording.mcap_file\n"
                             f"print(json.dumps(recording.analysis.analyze({path!r})['channels']['front']))", tmp_path)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == json.loads(json.dumps(analyze(path)["channels"]["front"]))
    assert json.loads(result.stdout)["peak_voltage"] == 2000.0


def test_writing_a_recording_without_ament_index_python_names_what_is_missing(tmp_path):
    result = run_without_ros("from recording.message_definitions import DefinitionNotFoundError, full_definition\n"
                             "try:\n    full_definition('std_msgs/msg/String')\n"
                             "except DefinitionNotFoundError as error:\n    print(error)\n", tmp_path)
    assert result.returncode == 0, result.stderr
    assert "ament_index_python is not installed" in result.stdout
    assert "reading and analysing recordings does not need it" in result.stdout
