"""The main() of every node: init, spin until Ctrl-C / SIGTERM / external shutdown, clean up."""
from __future__ import annotations

from collections.abc import Callable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node


def run_node(make_node: Callable[[], Node], name: str, executor: Callable[[], Executor] = SingleThreadedExecutor,
             args=None) -> int:
    """Spin the node built by ``make_node``; exit status 1 when it cannot start (bad configuration or file)."""
    rclpy.init(args=args)
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
