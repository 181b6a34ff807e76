"""Start the stack's nodes as processes, prefix their output, stop them cleanly (ros2 launch stand-in).

    python -m softblock_ros.launcher --nodes assembly_state,planner --params my_params.yaml
    python -m softblock_ros.launcher --nodes hv_driver --discovery-range subnet --domain-id 7   # the rig PC

The nodes, their parameter files, niceness, namespace and network settings come from the stack description
(config/stack.yaml, softblock_ros.stack); the network options override the file's (softblock_ros.network).
Each node runs as ``python -m <module> --ros-args --params-file <its files> [--params-file <params>]
[-r __ns:=<namespace>]`` in its own process group, so a terminal's Ctrl-C reaches only the launcher, which
then stops the nodes in reverse start order: SIGINT, then SIGKILL after ``stop_timeout``. The launcher exits
non-zero when a node dies on its own. SIGHUP (the terminal closed) is a stop like SIGINT and SIGTERM. A node
never outlives the launcher: each is started with the parent-death signal SIGTERM (Linux prctl
PR_SET_PDEATHSIG), so a SIGKILLed launcher's nodes stop as on a Ctrl-C. What a node starts itself (e.g. the HV
driver's supervisor) is not the launcher's child and keeps its own life. As a library:
``with Stack(nodes=["planner"]) as stack: ...``.
"""
from __future__ import annotations

import argparse
import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TextIO

from .network import NetworkSettings, describe, parse_discovery_range, parse_domain_id, parse_static_peers
from .parameter_files import check_parameter_file
from .stack import StackDescription, check_namespace, load_stack

DEFAULT_STOP_TIMEOUT = 10.0  # [s] per node, before SIGKILL
PUMP_DRAIN_TIMEOUT = 10.0  # [s] to copy a stopped node's last output (bounded: a grandchild may hold the pipe)
PR_SET_PDEATHSIG = 1  # linux/prctl.h
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
_prctl = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None


def _die_with(launcher_pid: int):
    """A Popen preexec_fn: the child gets SIGTERM when the launcher ends, however it ends.

    The kernel sends the signal when the thread that forked the child exits; the launcher starts its nodes
    from its main thread. A launcher that died before the prctl took effect is caught by the getppid check.
    The function is looked up before the fork, so the child only makes the call."""
    def preexec() -> None:
        if _prctl is None:
            return
        if _prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0 or os.getppid() != launcher_pid:
            os._exit(1)  # cannot be tied to the launcher, or it is gone already: do not start
    return preexec


class NodeDied(RuntimeError):
    """A node process exited while the stack was running."""


class OutputWatch:
    """The first line of one node's output that contains a text (``line``: None until it came)."""

    def __init__(self, node: str, text: str):
        self.node, self.text = node, text
        self.line: str | None = None
        self.settled = threading.Event()  # the line came, or the node's output ended without it


class Stack:
    """The node processes of one stack; a context manager that stops them in reverse order on exit."""

    def __init__(self, nodes: Iterable[str] | None = None, params: str | Path | None = None,
                 env: Mapping[str, str] | None = None, output: TextIO | None = None,
                 stop_timeout: float = DEFAULT_STOP_TIMEOUT, namespace: str | None = None,
                 description: StackDescription | None = None, network: NetworkSettings = NetworkSettings()):
        self.description = description or load_stack()
        self.nodes = list(self.description.default_names if nodes is None else nodes)
        unknown = [name for name in self.nodes if name not in self.description.names]
        if unknown:
            raise ValueError(f"unknown nodes {unknown}; known: {', '.join(self.description.names)}")
        if params is not None and not Path(params).is_file():
            raise ValueError(f"params file {params} does not exist")
        if params is not None:
            check_parameter_file(params)
        self.params = params
        # e.g. "/robot1": every node's relative names move under it
        self.namespace = self.description.namespace if namespace is None else check_namespace(namespace, "namespace")
        # DDS discovery: the options' network settings over the stack file's over the environment's
        self.network = network.over(self.description.network)
        self.env = self.network.environment({**os.environ, **(env or {}), "PYTHONUNBUFFERED": "1"})
        self.output = output or sys.stdout
        self.stop_timeout = stop_timeout
        self.processes: dict[str, subprocess.Popen] = {}
        self._stop_requested = False  # a plain flag: request_stop() runs in signal handlers
        self._output_lock = threading.Lock()
        self._pumps: list[threading.Thread] = []
        self._watches: list[OutputWatch] = []

    def watch(self, node: str, text: str) -> OutputWatch:
        """Note the first line of ``node``'s output that contains ``text`` (call before start())."""
        watch = OutputWatch(node, text)
        self._watches.append(watch)
        return watch

    def command(self, name: str) -> list[str]:
        spec = self.description.node(name)
        ros_args = [arg for path in (*spec.parameters, *([self.params] if self.params else []))
                    for arg in ("--params-file", str(path))]
        if self.namespace:
            ros_args += ["-r", f"__ns:={self.namespace}"]
        return [sys.executable, "-m", spec.module, *spec.arguments, *(["--ros-args", *ros_args] if ros_args else [])]

    def start(self) -> Stack:
        self._say("network", describe(self.env))
        for name in self.nodes:
            process = subprocess.Popen(self.command(name), env=self.env, stdin=subprocess.DEVNULL,
                                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                       process_group=0, preexec_fn=_die_with(os.getpid()))
            if self.description.node(name).niceness:
                niceness = min(os.getpriority(os.PRIO_PROCESS, 0) + self.description.node(name).niceness, 19)
                os.setpriority(os.PRIO_PROCESS, process.pid, niceness)
            self.processes[name] = process
            pump = threading.Thread(target=self._pump, args=(name, process), daemon=True)
            pump.start()
            self._pumps.append(pump)
        return self

    def wait_for(self, watch: OutputWatch, timeout: float) -> str | None:
        """The watched line once its node printed it; None if the node's output ended first (it exited:
        ``dead()`` then has its code) or ``timeout`` passed."""
        if watch.settled.wait(timeout) and watch.line is None:
            try:  # the output ends a moment before the process can be reaped
                self.processes[watch.node].wait(self.stop_timeout)
            except subprocess.TimeoutExpired:
                pass  # a node that closed its output and lives on
        return watch.line

    def _pump(self, name: str, process: subprocess.Popen) -> None:
        watches = [watch for watch in self._watches if watch.node == name]
        for line in process.stdout:
            for watch in watches:
                if watch.line is None and watch.text in line:
                    watch.line = line.rstrip("\n")
                    watch.settled.set()
            with self._output_lock:
                self.output.write(f"[{name}] {line}")
                self.output.flush()
        for watch in watches:
            watch.settled.set()

    def dead(self) -> dict[str, int]:
        """Exit codes of node processes that have ended."""
        return {name: p.returncode for name, p in self.processes.items() if p.poll() is not None}

    def request_stop(self) -> None:
        """Make ``wait()`` return; ``stop()`` then stops the nodes.

        Safe in a signal handler because it only sets a flag. Anything that takes a lock (``Event.set``)
        deadlocks when the signal lands while the main thread holds that lock, e.g. inside ``Event.wait``.
        """
        self._stop_requested = True

    def wait(self, poll_interval: float = 0.2) -> None:
        """Block until ``request_stop()`` or ``stop()``; NodeDied if a node ends first."""
        while not self._stop_requested:
            dead = self.dead()
            if dead:
                raise NodeDied(", ".join(f"node {n} exited with code {c}" for n, c in dead.items()))
            time.sleep(poll_interval)

    def stop(self) -> dict[str, int]:
        """Stop the nodes in reverse start order (SIGINT, then SIGKILL after the timeout); their exit codes.

        The SIGKILL goes to the node's whole process group, so what the node started (e.g. the simulated HV
        supply of ``hv_driver``) ends with it.
        """
        self._stop_requested = True
        for name in reversed(list(self.processes)):
            process = self.processes[name]
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
                try:
                    process.wait(self.stop_timeout)
                except subprocess.TimeoutExpired:
                    self._say(name, f"did not stop within {self.stop_timeout} s, killing it")
                    os.killpg(process.pid, signal.SIGKILL)  # not yet reaped: the group id is still its own
                    process.wait()
        for pump in self._pumps:
            pump.join(timeout=PUMP_DRAIN_TIMEOUT)
        return {name: p.returncode for name, p in self.processes.items()}

    def _say(self, name: str, text: str) -> None:
        with self._output_lock:
            self.output.write(f"[launcher] {name}: {text}\n")
            self.output.flush()

    def __enter__(self) -> Stack:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def _option(parse):
    """An argparse type from a network field's parser (its error message becomes argparse's)."""
    def convert(text: str):
        try:
            return parse(text)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
    return convert


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m softblock_ros.launcher", description=__doc__.split("\n")[0])
    parser.add_argument("--nodes", help="comma-separated nodes to start, in order (default: every node of the stack not marked optional)")
    parser.add_argument("--params", help="ROS parameter YAML passed to every node after its own files (--params-file)")
    parser.add_argument("--namespace", help="namespace of every node, e.g. /robot1 (default: the stack's)")
    parser.add_argument("--stack", type=Path, help="stack description (default: config/stack.yaml)")
    parser.add_argument("--stop-timeout", type=float, default=DEFAULT_STOP_TIMEOUT,
                        help="seconds each node gets to stop after SIGINT before SIGKILL")
    network = parser.add_argument_group("network (default: the stack file's network section, else the environment)")
    network.add_argument("--discovery-range", type=_option(parse_discovery_range),
                         help="ROS_AUTOMATIC_DISCOVERY_RANGE of the nodes: localhost, subnet, system_default or off")
    network.add_argument("--static-peers", type=_option(parse_static_peers),
                         help="ROS_STATIC_PEERS of the nodes: addresses or host names, separated by ; or ,")
    network.add_argument("--domain-id", type=_option(parse_domain_id),
                         help="ROS_DOMAIN_ID of the nodes, the same on every machine of the stack")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        nodes = None if args.nodes is None else [n for n in args.nodes.split(",") if n]
        description = load_stack(args.stack) if args.stack else None
        network = NetworkSettings(args.discovery_range, args.static_peers, args.domain_id)
        stack = Stack(nodes, args.params, stop_timeout=args.stop_timeout, namespace=args.namespace,
                      description=description, network=network)
    except (ValueError, OSError) as error:
        print(f"launcher: {error}", file=sys.stderr)
        return 2
    for signum in STOP_SIGNALS:
        signal.signal(signum, lambda *_: stack.request_stop())
    stack.start()
    try:
        stack.wait()
        status = 0
    except NodeDied as error:
        print(f"launcher: {error}; stopping the others", file=sys.stderr)
        status = 1
    codes = stack.stop()
    print(f"launcher: stopped ({', '.join(f'{n}={c}' for n, c in codes.items())})", file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
