"""Two emulated hosts joined by an emulated link, held until quit (root; Linux network namespaces).

    sudo .venv/bin/python -m netlab --hosts rig,workstation --delay-s 0.05 --jitter-s 0.01 --loss 0.05

Prints one JSON line when the hosts are up (namespaces, devices, addresses, the conditions), then reads one
command per line on stdin and answers each with one JSON line on stdout:

    set delay_s=0.05 jitter_s=0.01 loss=0.05    change the conditions (any subset)
    partition                                   cut the link (frames in flight too)
    heal                                        restore it
    stats                                       frames per direction: received, delivered, lost, ...
    quit                                        (or end of input, SIGINT, SIGTERM)

Run programs on a host with ``ip netns exec <namespace> <command>``. On exit everything still running in
the namespaces is killed and the namespaces are deleted; leftovers of a run that was killed are removed at
the next start.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
from dataclasses import asdict

from .hosts import DEFAULT_SUBNET, HostsError, create_hosts, remove_hosts, remove_leftovers
from .link import Conditions, Link, conditions_from

MAX_COMMAND = 1024  # [bytes] longest command line read


def reply(**fields) -> None:
    print(json.dumps(fields), flush=True)


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m netlab", description=__doc__.split("\n")[0])
    parser.add_argument("--hosts", default="rig,workstation", help="names of the two hosts (default: %(default)s)")
    parser.add_argument("--subnet", default=DEFAULT_SUBNET, help="private /24 of the link (default: %(default)s)")
    parser.add_argument("--delay-s", type=float, default=0.0, help="one-way delay [s]")
    parser.add_argument("--jitter-s", type=float, default=0.0, help="uniform delay variation, +- [s]")
    parser.add_argument("--loss", type=float, default=0.0, help="fraction of frames lost, each direction (0..1)")
    parser.add_argument("--seed", type=int, default=None, help="seed of the loss and jitter draws")
    return parser.parse_args(argv)


def execute(link: Link, line: str) -> bool:
    """Run one command line; False when it asks to quit."""
    command, _, rest = line.strip().partition(" ")
    if command == "quit":
        reply(ok=True, message="quitting")
        return False
    if command == "set":
        link.conditions = conditions_from(rest, link.conditions)
        reply(ok=True, conditions=asdict(link.conditions), partitioned=link.partitioned)
    elif command == "partition":
        link.partition()
        reply(ok=True, partitioned=True)
    elif command == "heal":
        link.heal()
        reply(ok=True, partitioned=False)
    elif command == "stats":
        reply(ok=True, stats=link.stats(), conditions=asdict(link.conditions), partitioned=link.partitioned)
    elif command:
        raise ValueError(f"unknown command {command!r}; known: set, partition, heal, stats, quit")
    return True


def serve(link: Link, stop: threading.Event) -> None:
    """Carry frames and answer commands from stdin until quit, end of input or ``stop``."""
    stdin = sys.stdin.fileno()
    pending = b""
    while not stop.is_set():
        if not link.poll(0.2, [stdin]):
            continue
        chunk = os.read(stdin, 4096)
        if not chunk:
            return
        pending += chunk
        while b"\n" in pending:
            line, pending = pending.split(b"\n", 1)
            try:
                if not execute(link, line.decode("utf-8", "replace")):
                    return
            except ValueError as error:
                reply(ok=False, error=str(error))
        if len(pending) > MAX_COMMAND:
            reply(ok=False, error=f"command longer than {MAX_COMMAND} bytes; discarded")
            pending = b""


def main(argv=None) -> int:
    args = parse_args(argv)
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    try:
        conditions = Conditions(args.delay_s, args.jitter_s, args.loss)
        names = tuple(args.hosts.split(","))
        removed = remove_leftovers()
        hosts, fds = create_hosts(names, args.subnet)
    except (ValueError, HostsError, OSError) as error:
        print(f"netlab: {error}", file=sys.stderr)
        return 2
    link = Link(*fds, conditions, rng=args.seed)
    try:
        reply(ready=True, hosts={h.name: {"namespace": h.namespace, "device": h.device, "address": h.address}
                                 for h in hosts},
              conditions=asdict(conditions), removed_leftovers=removed)
        serve(link, stop)
    finally:
        link.close()
        for fd in fds:
            os.close(fd)
        remove_hosts(hosts)
    return 0


if __name__ == "__main__":
    sys.exit(main())
