"""Record the stack's topics to MCAP, replay, inspect, recover and analyse recordings.

`python -m softblock_ros.recording {record,play,info,recover,analyze} ...`. ROS arguments go
after `--ros-args` (e.g. `--ros-args -r __ns:=/robot1`). rclpy is imported only by the record
and play subcommands.
"""
import argparse
import json
import os
import sys

from mcap.exceptions import McapError

from .mcap_file import COMPRESSIONS, DEFAULT_CHUNK_SIZE, describe, recover


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m softblock_ros.recording",
                                     description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)

    record = commands.add_parser("record", help="record topics to an MCAP file until Ctrl-C")
    # Options left out keep the node's parameters (defaults, or a --params-file after --ros-args).
    record.add_argument("-o", "--output", help="MCAP file to write (default: recording.mcap)")
    record.add_argument("topics", nargs="*", help="topics to record (default: all discovered)")
    record.add_argument("--exclude", help="regex of topics not recorded in all-topics mode "
                        "(default: /rosout and /parameter_events)")
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
    play.add_argument("--namespace", default="",
                      help="publish every topic under this namespace (e.g. /replay), away from "
                      "a live stack")

    info = commands.add_parser("info", help="topics, types, counts and QoS of a recording")
    info.add_argument("recording")
    info.add_argument("--json", action="store_true", help="print JSON instead of text")

    rescue = commands.add_parser("recover", help="rewrite a truncated recording as a valid one")
    rescue.add_argument("recording")
    rescue.add_argument("-o", "--output", help="default: <name>.recovered.mcap")

    analyze = commands.add_parser("analyze", help="plots and summary of a grasp recording")
    analyze.add_argument("recording")
    analyze.add_argument("--out-dir", help="where <name>.png/.json go (default: beside it)")
    return parser


def _record(args, ros_args) -> int:
    from .recorder_node import run
    given = {"output": args.output, "topics": args.topics or None, "exclude": args.exclude,
             "compression": args.compression, "chunk_size": args.chunk_size,
             "flush_period": args.flush_period, "discovery_period": args.discovery_period}
    return run({name: value for name, value in given.items() if value is not None},
               ["--ros-args", *ros_args])


def _play(args, ros_args) -> int:
    from .playback import PlaybackOptions
    from .player_node import run
    options = PlaybackOptions(rate=args.rate, loop=args.loop, include=args.include,
                              exclude=args.exclude, start_offset=args.start_offset,
                              skip_unknown=args.skip_unknown, clock_frequency=args.clock,
                              delay=args.delay, include_commands=args.include_commands,
                              namespace=args.namespace)
    return run(args.recording, options, args.keep_alive, ["--ros-args", *ros_args])


def _info(args) -> int:
    details = describe(args.recording)
    if args.json:
        print(json.dumps(details, indent=2))
        return 0
    print(f"{details['path']}: profile {details['profile']!r}, {details['message_count']} "
          f"messages in {details['chunk_count']} chunks over {details['duration']:.3f} s")
    for topic, topic_info in details["topics"].items():
        print(f"  {topic}  {topic_info['type']}  {topic_info['count']} messages  "
              f"{'/'.join(topic_info['durability']) or 'no QoS recorded'}")
    return 0


def _recover(args) -> int:
    output = args.output or os.path.splitext(args.recording)[0] + ".recovered.mcap"
    result = recover(args.recording, output)
    print(result.message)
    return 0 if result.success else 1


def _analyze(args) -> int:
    from .analysis import format_summary, load, summarize
    from .analysis_plot import plot
    stem = os.path.splitext(os.path.basename(args.recording))[0]
    out_dir = args.out_dir or os.path.dirname(os.path.abspath(args.recording))
    os.makedirs(out_dir, exist_ok=True)
    data = load(args.recording)
    summary = summarize(data)
    with open(os.path.join(out_dir, stem + ".json"), "w", encoding="utf-8") as out:
        json.dump(summary, out, indent=2)
    plot(data, os.path.join(out_dir, stem + ".png"), title=stem)
    print(format_summary(summary))
    print(f"wrote {os.path.join(out_dir, stem)}.json and .png")
    return 0


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args = []
    if "--ros-args" in argv:
        split = argv.index("--ros-args")
        argv, ros_args = argv[:split], argv[split + 1:]
    args = _parser().parse_args(argv)
    try:
        if args.command == "record":
            return _record(args, ros_args)
        if args.command == "play":
            return _play(args, ros_args)
        return {"info": _info, "recover": _recover, "analyze": _analyze}[args.command](args)
    except (OSError, ValueError, McapError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1


def record_main() -> int:
    return main(["record", *sys.argv[1:]])


def play_main() -> int:
    return main(["play", *sys.argv[1:]])


def analyze_main() -> int:
    return main(["analyze", *sys.argv[1:]])
