"""Record the stack's topics to MCAP, replay, inspect, recover and analyse recordings.

`python -m softblock_ros.recording {record,play,info,recover,analyze,export} ...`. ROS arguments go
after `--ros-args` (e.g. `--ros-args -r __ns:=/robot1`). rclpy is imported only by the record
and play subcommands; info, recover, analyze and export are the core's (`python -m recording`, no ROS needed).
"""
import argparse
import sys

from mcap.exceptions import McapError

from recording.cli import add_file_commands, run_file_command
from recording.mcap_file import COMPRESSIONS, DEFAULT_CHUNK_SIZE


def _recorder_parameters() -> str:
    """The recorder node's parameters, for its --help (the options set them; the others come after --ros-args)."""
    from ..runner import parameter_list  # rclpy, which record imports anyway
    return parameter_list("recorder")


def _parser(record_epilog: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m softblock_ros.recording",
                                     description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)

    record = commands.add_parser("record", help="record topics to an MCAP file until Ctrl-C",
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=record_epilog)
    # Options left out keep the node's parameters (defaults, or a --params-file after --ros-args).
    record.add_argument("-o", "--output", help="MCAP file to write (default: recording.mcap); it must not exist")
    record.add_argument("--overwrite", action="store_true", default=None,
                        help="replace an existing output file (a link is replaced, never written through)")
    record.add_argument("topics", nargs="*", help="topics to record (default: all discovered)")
    record.add_argument("--exclude", help="regex of topics not recorded in all-topics mode "
                        "(default: /parameter_events; /rosout, the nodes' logs, is recorded)")
    record.add_argument("--compression", choices=sorted(COMPRESSIONS), help="default: zstd")
    record.add_argument("--chunk-size", type=int,
                        help=f"bytes per chunk (default: {DEFAULT_CHUNK_SIZE})")
    record.add_argument("--flush-period", type=float,
                        help="seconds between flushes to disk, bounds what SIGKILL loses "
                        "(default: 1.0)")
    record.add_argument("--discovery-period", type=float,
                        help="seconds between topic discovery (default: 1.0)")

    play = commands.add_parser("play", help="republish a recording with its timing and QoS")
    play.add_argument("recording")
    play.add_argument("--rate", type=float, default=1.0, help="speed factor")
    play.add_argument("--loop", action="store_true", help="start over at the end")
    play.add_argument("--include", default="", help="regex: play only matching topics")
    play.add_argument("--exclude", default="", help="regex: never play matching topics")
    play.add_argument("--start-offset", type=float, default=0.0,
                      help="seconds into the recording to start from")
    play.add_argument("--delay", type=float, default=0.0,
                      help="seconds to wait after advertising before playing, so subscribers "
                      "(a recorder, a fresh stack) match first")
    play.add_argument("--clock", type=float, default=0.0, metavar="HZ",
                      help="publish /clock (rosgraph_msgs/Clock) at this rate")
    play.add_argument("--skip-unknown", action="store_true",
                      help="play the other topics when a message type cannot be imported")
    play.add_argument("--keep-alive", action="store_true",
                      help="stay up after the end so latched topics remain available")
    play.add_argument("--include-commands", action="store_true",
                      help="also play command topics (hv/heartbeat, assembly/safe_voltage, action "
                      "internals), which a live HV driver obeys; left out by default")
    play.add_argument("--include-state", action="store_true",
                      help="play state topics (hv/state, assembly/current, camera/silhouette, /diagnostics, "
                      "/rosout) under their own names, where live clients take them for the live state; by "
                      "default they go under /replay")
    play.add_argument("--namespace", default="",
                      help="publish every topic under this namespace (e.g. /replay), away from "
                      "a live stack")

    add_file_commands(commands)
    return parser


def _record(args, ros_args) -> int:
    from .recorder_node import run
    given = {"output": args.output, "topics": args.topics or None, "exclude": args.exclude,
             "overwrite": args.overwrite, "compression": args.compression, "chunk_size": args.chunk_size,
             "flush_period_s": args.flush_period, "discovery_period_s": args.discovery_period}
    return run({name: value for name, value in given.items() if value is not None},
               ["--ros-args", *ros_args])


def _play(args, ros_args) -> int:
    from recording.playback import PlaybackOptions
    from .player_node import run
    options = PlaybackOptions(rate=args.rate, loop=args.loop, include=args.include,
                              exclude=args.exclude, start_offset_s=args.start_offset,
                              skip_unknown=args.skip_unknown, clock_frequency_hz=args.clock,
                              delay_s=args.delay, include_commands=args.include_commands,
                              namespace=args.namespace, include_state=args.include_state)
    return run(args.recording, options, args.keep_alive, ["--ros-args", *ros_args])


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args = []
    if "--ros-args" in argv:
        split = argv.index("--ros-args")
        argv, ros_args = argv[:split], argv[split + 1:]
    args = _parser(_recorder_parameters() if argv[:1] == ["record"] else None).parse_args(argv)
    if args.command not in ("record", "play"):
        return run_file_command(args)
    try:
        return _record(args, ros_args) if args.command == "record" else _play(args, ros_args)
    except (OSError, ValueError, McapError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1


def record_main() -> int:
    return main(["record", *sys.argv[1:]])


def play_main() -> int:
    return main(["play", *sys.argv[1:]])

