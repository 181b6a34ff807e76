"""Recordings without ROS: inspect, recover, analyse and export MCAP files.

    python -m recording {info,recover,analyze,export} FILE ...
    python -m recording export --csv DIR FILE     # one CSV per topic (recording.export)

The same subcommands are part of `python -m softblock_ros.recording`, which adds record and play.
"""
import argparse
import json
import os
import sys

import zstandard
from mcap.exceptions import McapError

from .mcap_file import describe, recover


def add_file_commands(commands) -> None:
    """The info, recover, analyze and export subcommands, on an argparse subparsers object."""
    info = commands.add_parser("info", help="topics, types, counts and QoS of a recording")
    info.add_argument("recording")
    info.add_argument("--json", action="store_true", help="print JSON instead of text")

    rescue = commands.add_parser("recover", help="rewrite a truncated recording as a valid one")
    rescue.add_argument("recording")
    rescue.add_argument("-o", "--output", help="default: <name>.recovered.mcap; an existing one is refused")
    rescue.add_argument("--overwrite", action="store_true",
                        help="replace an existing output (a link is replaced, never written through)")

    analyze = commands.add_parser("analyze", help="plots and summary of a grasp recording")
    analyze.add_argument("recording")
    analyze.add_argument("--out-dir", help="where <name>.png/.json go (default: beside it)")
    analyze.add_argument("--no-plot", action="store_true",
                         help="the summary only (<name>.json), no PNG: drawing takes most of the time")

    export = commands.add_parser("export", help="one CSV file per topic (flattened fields, SI units, time in s)")
    export.add_argument("recording")
    export.add_argument("--csv", required=True, metavar="DIR", help="directory for <topic>.csv (created)")


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
    result = recover(args.recording, output, args.overwrite)
    print(result.message)
    return 0 if result.success else 1


def _analyze(args) -> int:
    from .analysis import format_summary, load, summarize
    stem = os.path.splitext(os.path.basename(args.recording))[0]
    out_dir = args.out_dir or os.path.dirname(os.path.abspath(args.recording))
    os.makedirs(out_dir, exist_ok=True)
    data = load(args.recording)
    summary = summarize(data)
    with open(os.path.join(out_dir, stem + ".json"), "w", encoding="utf-8") as out:
        json.dump(summary, out, indent=2)
    if not args.no_plot:
        from .analysis_plot import plot
        plot(data, os.path.join(out_dir, stem + ".png"), title=stem)
    print(format_summary(summary))
    print(f"wrote {os.path.join(out_dir, stem)}.json{'' if args.no_plot else ' and .png'}")
    return 0


def _export(args) -> int:
    from .export import csv_name, export_csv
    counts = export_csv(args.recording, args.csv)
    for topic, rows in sorted(counts.items()):
        print(f"{topic}: {rows} rows -> {os.path.join(args.csv, csv_name(topic))}")
    return 0


FILE_COMMANDS = {"info": _info, "recover": _recover, "analyze": _analyze, "export": _export}


def run_file_command(args) -> int:
    """Run a parsed info/recover/analyze/export command; a bad file is one line on stderr and exit status 1."""
    try:
        return FILE_COMMANDS[args.command](args)
    # A chunk of corrupt compressed data: zstd raises ZstdError, python-lz4 RuntimeError.
    except (OSError, ValueError, McapError, zstandard.ZstdError, RuntimeError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m recording", description=__doc__.split("\n\n")[0])
    add_file_commands(parser.add_subparsers(dest="command", required=True))
    return run_file_command(parser.parse_args(argv))


def analyze_main() -> int:
    return main(["analyze", *sys.argv[1:]])
