"""The ``planner`` command line: argparse subcommands collected from the modules of this package.

Each module ``planner/cli/<name>_cmd.py`` defines ``register(subparsers)``, which adds its
subcommand(s) and sets ``handler`` (a function taking the parsed args and returning an exit
code) via ``set_defaults``. New commands need a new module only; nothing here changes.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m planner", description="Soft building-block planner tools.")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module_info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if module_info.name.endswith("_cmd"):
            importlib.import_module(f"{__name__}.{module_info.name}").register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.handler(args) or 0)
    except (ValueError, OSError) as error:  # a bad input or a file that cannot be read or written: one line
        print(f"error: {error}", file=sys.stderr)
        return 2
