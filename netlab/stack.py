"""The softblock stack split over two emulated hosts, as a lab runs it on two machines: the HV driver on the rig
PC, everything else on the workstation, an HV console on each (softblock_ros.hv_console --json --commands).

    with EmulatedHosts() as lab, TwoHostStack(lab, out_dir, domain_id=1) as stack:
        stack.rig.wait_state(lambda s: s["channels"]["back"]["voltage_v"] > 2350.0)
        grasp = stack.start_sequence("finger_grasp")

Every process runs under the launcher's network switch (``--discovery-range subnet --domain-id N``) and with
Fast DDS limited to UDPv4: its shared-memory transport would otherwise let two processes of this one machine
talk past the emulated link. Both hosts share this machine's cores, where on a lab bench the rig PC has its
own: the rig's processes run at a higher priority (RIG_NICENESS) and the sequencer's timeouts are widened
(SEQUENCER_PARAMETERS; restart_sequencer starts it with others). The recorder writes into ``out_dir``. Nothing
here imports ROS; the processes do.
"""
from __future__ import annotations

import json
import os
import queue
import re
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import yaml

from hv_driver.supervisor import DEFAULT_PERIOD_S, SLEW_CREDIT_PERIODS

from .emulated import EmulatedHosts

RIG_NODES = ("hv_driver",)
# The sequencer runs under a launcher of its own on the workstation, so that a test can restart it with other
# timeouts (restart_sequencer) while the rest of the stack runs on.
WORKSTATION_NODES = ("assembly_state", "planner", "sim_arm", "recorder")
SEQUENCER_STARTUP_TIMEOUT = 120.0  # [s] a sequencer's start and discovery on two loaded cores
COMMAND_TIMEOUT = 60.0  # [s] a console command, e.g. a ramp to 2.4 kV over a lossy link
RECORDER_TIMEOUT = 60.0  # [s] a recorder's start and subscriptions on two loaded cores
# The rig PC's processes (the driver and its simulated supply) share two cores with the workstation's and any
# other load here; starved, the simulated supply answered late and the driver rightly latched a LINK fault.
# Run above normal priority they stand for a rig PC of their own.
RIG_NICENESS = -20
# The sequencer's timeouts, widened from their defaults (0.5 s, 2 s): with both hosts on shared cores the driver
# was seen to stall for up to 1.6 s (a gap in its stamps on its own host's console, not a loss on the link), and
# across a lossy link a lost request or reply is repaired only at the writer's next periodic heartbeat (Fast
# DDS: every DDS_REPAIR_PERIOD_S). A service wait must cover three repairs: a lost request, a lost repair (or
# its heartbeat or acknowledgement) and a lost reply. With 5 s (one repair and a half) one lossy grasp in about
# twenty timed out waiting for hv/claim_control; a call needs four losses in a row to outlast 10 s.
DDS_REPAIR_PERIOD_S = 3.0
SEQUENCER_STATE_TIMEOUT_S = 2.0
SEQUENCER_SERVER_TIMEOUT_S = 3 * DDS_REPAIR_PERIOD_S + 1.0
SEQUENCER_PARAMETERS = {"state_timeout_s": SEQUENCER_STATE_TIMEOUT_S, "server_timeout_s": SEQUENCER_SERVER_TIMEOUT_S}
# A gap this long between two hv/state samples the driver sent one after the other (it publishes every 20 ms) is
# a stall of its process, not a late cycle.
STALL_S = 0.1


SERVING_LOG = "[sequencer]: serving /sequencer/run"
LOST_DRIVER_LOG = re.compile(r"^\[sequencer\] \[ERROR\] \[(\d+\.\d+)\] \[sequencer\]: HV driver lost", re.MULTILINE)
STEP_DURATION = re.compile(r"^  (\S+) +(\d+\.\d+) s$", re.MULTILINE)  # run_sequence's result lines


def channels_below(state: dict, volts: float) -> bool:
    """Every channel of an hv/state record measured and set below ``volts``."""
    return all(c["voltage_v"] < volts and c["setpoint_v"] < volts for c in state["channels"].values())


def driver_stalls(states: list[dict], since: float, until: float, longer_than_s: float = STALL_S) -> list[float]:
    """How long each stall of the driver held its ramps back [s], between the stamps ``since`` and ``until``: a gap
    longer than ``longer_than_s`` between two hv/state samples it sent one after the other (consecutive sequence
    numbers, so nothing was lost on the way), less the slew credit its first cycle after the stall takes
    (hv_driver.supervisor: at most SLEW_CREDIT_PERIODS nominal periods). Its ramps resume where they stopped,
    so they end that much later."""
    credit = SLEW_CREDIT_PERIODS * DEFAULT_PERIOD_S
    ordered = sorted(states, key=lambda state: state["sequence"])
    return [after["stamp"] - before["stamp"] - credit for before, after in zip(ordered, ordered[1:])
            if after["sequence"] == before["sequence"] + 1 and since <= before["stamp"] and after["stamp"] <= until
            and after["stamp"] - before["stamp"] > longer_than_s]


def driver_lost_logged(launcher_log: str, since: float) -> float | None:
    """When (time.time()) the sequencer first logged "HV driver lost" at or after ``since``, from its launcher's
    output, or None."""
    times = (float(stamp) for stamp in LOST_DRIVER_LOG.findall(launcher_log))
    return next((stamp for stamp in times if stamp >= since), None)


def step_durations(log: str) -> dict[str, float]:
    """The step durations [s] that ``softblock_ros.run_sequence`` printed with its result."""
    return {name: float(seconds) for name, seconds in STEP_DURATION.findall(log)}


class Console:
    """An HV console process: its JSON records as they arrive, and its commands."""

    def __init__(self, process: subprocess.Popen, name: str):
        self.process, self.name = process, name
        self.records: list[dict] = []
        self._lock = threading.Lock()
        self._replies: queue.Queue[dict] = queue.Queue()
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        for line in self.process.stdout:
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue  # a log line
            if record.get("type") == "reply":
                self._replies.put(record)
            else:
                with self._lock:
                    self.records.append(record)

    def snapshot(self) -> list[dict]:
        """Every record received so far."""
        with self._lock:
            return list(self.records)

    def states(self, since: float = 0.0) -> list[dict]:
        """hv/state samples received at or after ``since`` (time.time())."""
        with self._lock:
            return [r for r in self.records if r["type"] == "state" and r["t"] >= since]

    def controls(self, since: float = 0.0) -> list[dict]:
        with self._lock:
            return [r for r in self.records if r["type"] == "control" and r["t"] >= since]

    def wait_state(self, predicate: Callable[[dict], object], timeout: float, since: float = 0.0) -> dict:
        """The first hv/state sample received since ``since`` that satisfies ``predicate``."""
        deadline = time.monotonic() + timeout
        while True:
            found = next((state for state in self.states(since) if predicate(state)), None)
            if found is not None:
                return found
            if time.monotonic() > deadline:
                raise TimeoutError(f"{self.name} console: no matching hv/state within {timeout:g} s")
            time.sleep(0.02)

    def command(self, line: str, timeout: float = COMMAND_TIMEOUT) -> dict:
        """Send one command and return its answer ({"ok", "message"})."""
        self.process.stdin.write(line + "\n")
        self.process.stdin.flush()
        try:
            return self._replies.get(timeout=timeout)
        except queue.Empty:
            raise TimeoutError(f"{self.name} console: no answer to {line!r} within {timeout:g} s") from None


class TwoHostStack:
    """Launchers and consoles on the lab's ``rig`` and ``workstation`` hosts; node output in ``out``."""

    def __init__(self, lab: EmulatedHosts, out: Path, domain_id: int, env: Mapping[str, str] | None = None):
        self.lab, self.out, self.domain_id = lab, Path(out), domain_id
        self.params = self.out / "params.yaml"
        self.env = {**(env or os.environ), "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4", "PYTHONUNBUFFERED": "1",
                    "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_DOMAIN_ID": str(domain_id)}
        self.launchers: dict[str, subprocess.Popen] = {}
        self._sequencer_starts = 0
        self.logs: dict[str, Path] = {}
        self.rig: Console | None = None
        self.workstation: Console | None = None

    def _log(self, name: str):
        self.logs[name] = self.out / f"{name}.log"
        return open(self.logs[name], "w")

    def start(self) -> TwoHostStack:
        self.out.mkdir(parents=True, exist_ok=True)
        recording = str(self.out / "workstation.mcap")
        self.params.write_text(yaml.safe_dump({"recorder": {"ros__parameters": {"output": recording}}}))
        for host, nodes, niceness in (("rig", RIG_NODES, RIG_NICENESS), ("workstation", WORKSTATION_NODES, 0)):
            self.launchers[host] = self._launch(host, nodes, niceness, self.params, host)
        self.restart_sequencer(SEQUENCER_PARAMETERS)
        self.rig, self.workstation = (self.start_console(host) for host in ("rig", "workstation"))
        return self

    def _launch(self, host: str, nodes: tuple[str, ...], niceness: int, params: Path,
                log_name: str) -> subprocess.Popen:
        command = ["nice", "-n", str(niceness), sys.executable, "-m", "softblock_ros.launcher",
                   "--nodes", ",".join(nodes), "--discovery-range", "subnet", "--domain-id", str(self.domain_id),
                   "--params", str(params)]
        with self._log(log_name) as log:
            return self.lab.start(host, command, self.env, stdout=log, stderr=subprocess.STDOUT)

    def restart_sequencer(self, parameters: Mapping[str, float]) -> None:
        """The workstation's sequencer (stopped first if running) started with ``parameters``; the output of its
        n-th start in ``sequencer_<n>.log`` (``logs["sequencer"]``). It serves once wait_sequencer_serving returns."""
        if "sequencer" in self.launchers:
            self.lab.stop(self.launchers.pop("sequencer"), timeout=30.0)
        self._sequencer_starts += 1
        name = f"sequencer_{self._sequencer_starts}"
        params = self.out / f"{name}_params.yaml"
        params.write_text(yaml.safe_dump({"sequencer": {"ros__parameters": dict(parameters)}}))
        self.launchers["sequencer"] = self._launch("workstation", ("sequencer",), 0, params, name)
        self.logs["sequencer"] = self.logs[name]

    def wait_sequencer_serving(self, timeout: float = SEQUENCER_STARTUP_TIMEOUT) -> None:
        """Until the sequencer serves sequencer/run (it has looked for another one and found none)."""
        deadline = time.monotonic() + timeout
        while SERVING_LOG not in self.logs["sequencer"].read_text():
            if self.launchers["sequencer"].poll() is not None or time.monotonic() > deadline:
                raise TimeoutError(f"the sequencer did not serve within {timeout:g} s: "
                                   f"{self.logs['sequencer'].read_text()[-2000:]}")
            time.sleep(0.1)

    def start_console(self, host: str) -> Console:
        with self._log(f"{host}_console") as log:
            process = self.lab.start(host, [sys.executable, "-m", "softblock_ros.hv_console", "--json", "--commands"],
                                     self.env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log, text=True)
        return Console(process, host)

    def start_sequence(self, name: str, log_name: str = "run_sequence") -> subprocess.Popen:
        """``softblock_ros.run_sequence <name>`` on the workstation; its output in ``<log_name>.log``."""
        with self._log(log_name) as log:
            return self.lab.start("workstation", [sys.executable, "-m", "softblock_ros.run_sequence", name,
                                                  "--server-timeout", "60"],
                                  self.env, stdout=log, stderr=subprocess.STDOUT)

    def start_grasp_to_peak(self, volts: float, log_name: str, timeout: float) -> tuple[subprocess.Popen, dict | None]:
        """The finger grasp started; returns it with the first rig hv/state whose back fingers exceed ``volts``,
        or with None if the grasp ended before (its log says why)."""
        started = time.time()
        process = self.start_sequence("finger_grasp", log_name)
        state = self.rig.wait_state(lambda s: s["channels"]["back"]["voltage_v"] > volts or process.poll() is not None,
                                    timeout, started)
        return process, None if process.poll() is not None else state

    def start_recorder(self, output: Path, topics: tuple[str, ...] = ("hv/state",), log_name: str = "recorder",
                       timeout: float = RECORDER_TIMEOUT) -> subprocess.Popen:
        """A recorder of ``topics`` on the workstation, writing ``output`` (stop it to finish the file); returns
        once it has subscribed to every topic (it waits for each to be offered)."""
        with self._log(log_name) as log:
            process = self.lab.start("workstation", [sys.executable, "-m", "softblock_ros.recording", "record",
                                                     "--output", str(output), *topics],
                                     self.env, stdout=log, stderr=subprocess.STDOUT)
        expected = [f"recording /{topic.lstrip('/')} " for topic in topics]
        deadline = time.monotonic() + timeout
        while not all(line in self.logs[log_name].read_text() for line in expected):
            if process.poll() is not None or time.monotonic() > deadline:
                raise TimeoutError(f"the recorder did not subscribe to {', '.join(topics)} within {timeout:g} s "
                                   f"(exit code {process.poll()}): {self.logs[log_name].read_text()[-2000:]}")
            time.sleep(0.1)
        return process

    def stop(self) -> dict[str, int]:
        """Consoles, then launchers (each stops its nodes); exit codes by name. What each console received
        is kept in ``<host>_console.jsonl`` for a look after a failure."""
        codes = {}
        for console in (self.rig, self.workstation):
            if console is not None:
                with open(self.out / f"{console.name}_console.jsonl", "w") as stream:
                    stream.writelines(json.dumps(record) + "\n" for record in console.snapshot())
        # The consoles, then the sequencer (its safe stop needs the driver), then every other node at once.
        stages = ((("workstation_console", self.workstation and self.workstation.process),
                   ("rig_console", self.rig and self.rig.process)),
                  (("sequencer_launcher", self.launchers.get("sequencer")),),
                  tuple((f"{host}_launcher", self.launchers.get(host)) for host in ("workstation", "rig")))
        for stage in stages:
            running = [(name, process) for name, process in stage if process is not None]
            returned = self.lab.stop_together([process for _, process in running], timeout=30.0)
            codes.update(zip((name for name, _ in running), returned))
        return codes

    def __enter__(self) -> TwoHostStack:
        try:
            return self.start()
        except BaseException:
            self.stop()
            raise

    def __exit__(self, *exc) -> None:
        self.stop()
