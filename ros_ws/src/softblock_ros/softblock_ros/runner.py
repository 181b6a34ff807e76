"""The main() of every node: init, spin until Ctrl-C / SIGTERM / external shutdown, clean up.

A callback that raises (a timer, a subscription, a service) is logged and the node keeps running: one
bad message or one failing computation must not end the node, and with it (under the launcher) the stack.
``--help`` / ``-h`` prints the node's parameters (its schema) and exits 0 without starting it. The
``--params-file`` files are checked (softblock_ros.parameter_files) before rclpy parses them, so a bad file
ends the start with one line instead of rcl's traceback; what rcl refuses all the same (a file the check has not
foreseen, a remap such as ``-r __ns:=a b``) is one line too.
"""
from __future__ import annotations

import os
import re
import signal
import sys
import traceback
from collections.abc import Callable, Sequence

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node

from .parameter_files import check_parameter_file
from .parameters import NODE_SCHEMAS, node_schema
from .stack import check_namespace


def _stop_quietly(signum, frame) -> None:
    """Python's part of Ctrl-C / SIGTERM: nothing. rclpy's handler, installed over this one by
    rclpy.init and chaining to it, shuts the context down and wakes the executor; spin then ends.

    Python's default KeyboardInterrupt would land at an arbitrary line instead, e.g. between a thread
    pool starting a callback worker and registering it, after which the interpreter waits for that
    worker forever at exit.
    """


RCLError = rclpy_implementation.RCLError
# rclpy's signal handling wakes the executor and shuts the context down, in that order and not as one step: a wake
# that lands before the shutdown lets spin see a live context and wait again, with nothing left to wake it (seen:
# about one Ctrl-C in ten left an idle node spinning). Spin therefore waits at most this long before it looks again.
STOP_CHECK_PERIOD_S = 0.25
# After the stop, callbacks still running on an executor's other threads end before their node is destroyed; one
# that takes longer than this is not waited for (the launcher's stop timeout bounds the rest).
CALLBACK_END_TIMEOUT_S = 10.0
_RCL_SOURCE = re.compile(r",? at /\S+:\d+")  # rcl's ", at /project/src/parse.c:258" after each cause


def rcl_problem(error: RuntimeError) -> str:
    """rcl's message in one line, without its source locations."""
    return " ".join(_RCL_SOURCE.sub("", str(error)).split())[:300]


_NAMESPACE_REMAP = re.compile(r"(?:[^:]*:)?__ns:=(.*)")  # -r [node:]__ns:=/robot1


def check_arguments(args: Sequence[str]) -> None:
    """ValueError (one line) for a ``--params-file`` (softblock_ros.parameter_files) or a namespace remap that rcl
    would refuse from inside rclpy.init (rcl reads them after --ros-args)."""
    args = list(args)
    args = args[args.index("--ros-args") + 1:] if "--ros-args" in args else []
    for flag, value in zip(args, args[1:]):
        if flag == "--params-file":
            check_parameter_file(value)
        elif flag in ("-r", "--remap") and (remap := _NAMESPACE_REMAP.fullmatch(value)):
            check_namespace(remap[1], f"-r {value.partition(':=')[0]}:", optional=False)


def init(args=None) -> None:
    """rclpy.init for a node process, with Ctrl-C / SIGTERM ending spin instead of raising anywhere.
    ValueError (one line) for a bad ``--params-file`` or namespace (check_arguments), before rclpy is initialized,
    and for anything else rcl refuses."""
    check_arguments(sys.argv if args is None else args)
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _stop_quietly)
    try:
        rclpy.init(args=args)
    except RCLError as error:
        raise ValueError(f"rcl refused the arguments: {rcl_problem(error)}") from None


def parameter_list(name: str) -> str:
    """The node's parameters, from its schema (softblock_ros.parameters), one a line."""
    return "\n".join([f"parameters of node {name}:", *(
        f"  {param.name} (default {param.default!r}; {param._range_text()}): {param.text()}"
        for param in node_schema(name))])


def usage(name: str) -> str:
    """The node's command line and its parameters."""
    lines = [f"usage: {os.path.basename(sys.argv[0]) or name} [--ros-args [-p NAME:=VALUE]... "
             "[--params-file FILE]... [-r __ns:=/NAMESPACE]]", ""]
    if name in NODE_SCHEMAS:
        lines.append(parameter_list(name))
    return "\n".join(lines)


def _asks_for_help(args) -> bool:
    """-h or --help among the node's own arguments (those before --ros-args)."""
    own = list(sys.argv[1:] if args is None else args)
    own = own[:own.index("--ros-args")] if "--ros-args" in own else own
    return "-h" in own or "--help" in own


def where(error: BaseException) -> str:
    """``file:line in function`` of the innermost frame of an exception's traceback."""
    frames = traceback.extract_tb(error.__traceback__)
    return f"{os.path.basename(frames[-1].filename)}:{frames[-1].lineno} in {frames[-1].name}" if frames else "?"


def spin_logging_errors(executor: Executor, logger, keep_spinning: Callable[[], bool] = lambda: True) -> None:
    """``executor.spin()``, except that an exception raised by a callback is logged in one line (at most once
    a second) and spinning goes on. Returns when the context is shut down (Ctrl-C, SIGTERM) or
    ``keep_spinning()`` turns false.

    The executor's own wait can raise too: rclpy 7.1 fails it with InvalidHandle when a callback on another
    thread destroys an entity (as a lifecycle cleanup does) while the wait set is being built. The next
    spin builds it afresh without that entity."""
    while executor.context.ok() and keep_spinning():
        try:
            executor.spin_once(timeout_sec=STOP_CHECK_PERIOD_S)
        except (KeyboardInterrupt, ExternalShutdownException):
            raise
        except Exception as error:  # any callback error: the node must keep serving
            if not executor.context.ok() or not keep_spinning():
                # Ctrl-C / SIGTERM shut the context down while the executor was taking a message; rclpy then
                # raises from the half-destroyed handle. That is the stop that was asked for, not a failure.
                return
            logger.error(f"a callback raised {type(error).__name__}: {str(error)[:200]} (at {where(error)}); "
                         "the node keeps running", throttle_duration_sec=1.0)


def shut_down_after_its_callbacks(executor: Executor, logger) -> None:
    """``executor.shutdown()`` once the callbacks still running on its threads have ended (at most
    CALLBACK_END_TIMEOUT_S). rclpy 7.1's shutdown means to wait for them but skips the wait (it tests the flag it has
    just set), so the wait is made here, on the executor's own record of running callbacks."""
    if not executor._work_tracker.wait(CALLBACK_END_TIMEOUT_S):
        logger.warning(f"callbacks still running {CALLBACK_END_TIMEOUT_S:g} s after the stop; the node is "
                       "destroyed under them")
    executor.shutdown(timeout_sec=0)


def run_node(make_node: Callable[[], Node], name: str, executor: Callable[[], Executor] = SingleThreadedExecutor,
             args=None) -> int:
    """Spin the node built by ``make_node``; exit status 1 when it cannot start (bad configuration or file).
    ``--help`` prints the usage and returns 0."""
    if _asks_for_help(args):
        print(usage(name))
        return 0
    try:
        init(args)
    except ValueError as error:
        print(f"[FATAL] [{name}]: cannot start: {error}", file=sys.stderr)
        return 1
    node = spinner = None
    try:
        node = make_node()
        spinner = executor()
        spinner.add_node(node)
        spin_logging_errors(spinner, node.get_logger())
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as error:
        if not rclpy.ok():
            # Ctrl-C / SIGTERM landed while the node or its executor was being built: rclpy refuses to create
            # anything more on the shut-down context. That is the stop that was asked for, not a failure.
            rclpy.logging.get_logger(name).info(f"stopped while starting ({type(error).__name__} on shutdown)")
            return 0
        if node is not None or not isinstance(error, (ValueError, OSError, RCLError)):
            raise
        problem = rcl_problem(error) if isinstance(error, RCLError) else error  # e.g. a namespace rcl refuses
        rclpy.logging.get_logger(name).fatal(f"cannot start: {problem}")
        return 1
    finally:
        if spinner is not None:
            shut_down_after_its_callbacks(spinner, node.get_logger())
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
