"""The main() of every node: init, spin until Ctrl-C / SIGTERM / external shutdown, clean up."""
from __future__ import annotations

import signal
from collections.abc import Callable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node


def _stop_quietly(signum, frame) -> None:
    """Python's part of Ctrl-C / SIGTERM: nothing. rclpy's handler, installed over this one by
    rclpy.init and chaining to it, shuts the context down and wakes the executor; spin then ends.

    Python's default KeyboardInterrupt would land at an arbitrary line instead, e.g. between a thread
    pool starting a callback worker and registering it, after which the interpreter waits for that
    worker forever at exit.
    """


def init(args=None) -> None:
    """rclpy.init for a node process, with Ctrl-C / SIGTERM ending spin instead of raising anywhere."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _stop_quietly)
    rclpy.init(args=args)


def run_node(make_node: Callable[[], Node], name: str, executor: Callable[[], Executor] = SingleThreadedExecutor,
             args=None) -> int:
    """Spin the node built by ``make_node``; exit status 1 when it cannot start (bad configuration or file)."""
    init(args)
    node = None
    try:
        node = make_node()
        spinner = executor()
        spinner.add_node(node)
        spinner.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # Ctrl-C / SIGTERM shut the context down while the executor was taking a message; rclpy then
        # raises from the half-destroyed handle. That is the stop that was asked for, not a failure.
        if rclpy.ok():
            raise
    except (ValueError, OSError) as error:
        if node is not None:
            raise
        rclpy.logging.get_logger(name).fatal(f"cannot start: {error}")
        return 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
