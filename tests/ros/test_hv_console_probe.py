"""`hv_console --probe PORT`: identifies the supply on a port, read-only, without starting ROS."""
import rclpy

from sim_fallback.keithley_supply import IDENTITY, SimulatedKeithley2290
from softblock_ros import hv_console


def test_probe_names_the_supply_and_its_node_parameters_without_starting_ros(capsys):
    with SimulatedKeithley2290() as sim:
        status = hv_console.main(["hv_console", "--probe", sim.port])
        received = {line.strip() for _, line in sim.command_log}
    out = capsys.readouterr().out
    assert status == 0, out
    assert f"found: keithley-2290 at 9600 baud, identity {IDENTITY!r}" in out
    assert f"node parameters: backend: serial, dialect: keithley-2290, ports: [{sim.port}], baudrate: 9600" in out
    assert received <= {"", "*IDN?"}
    assert not rclpy.ok()  # no context was initialised


def test_probe_of_a_missing_port_exits_2_naming_it(capsys):
    assert hv_console.main(["hv_console", "--probe", "/dev/no-such-port"]) == 2
    assert "cannot open '/dev/no-such-port'" in capsys.readouterr().err
