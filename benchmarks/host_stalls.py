"""Late wake-ups of a SCHED_FIFO thread per CPU, and whether the hypervisor took the CPU away (steal) meanwhile.

    scripts/with_env.sh python benchmarks/host_stalls.py [--seconds 300] [--busy 2] [--no-hog] [--threshold-ms 20]

One monitor process per CPU, pinned to it at SCHED_FIFO 48 where granted, waits 1 ms in select() on a pipe, over
and over. A wake-up later than the threshold is logged with its lateness (beyond the 1 ms asked for) and the steal
time of its own CPU and of all CPUs over that wait: the `steal` column of /proc/stat, read once per loop (the reading
after one wait is the reading before the next), counted by the guest in whole ticks. Steal is time the host ran
something else on the virtual CPU; no priority inside the guest helps. Beside the monitors, at normal priority:
`--busy` shell busy loops and (unless --no-hog) a memory hog that allocates and touches 400 MB over and over.
Writes docs/figures/host_stalls.json and docs/figures/host_stalls.png.
"""
import argparse
import gzip
import json
import multiprocessing
import multiprocessing.connection
import os
import re
import select
import subprocess
import sys
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from hv_driver.realtime import fifo, normal_priority  # noqa: E402

FIGURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "figures")
PRIORITY = 48
WAIT_S = 0.001
HOG_BYTES = 400_000_000
HOG = [sys.executable, "-c", "import numpy as np\nwhile True:\n"  # fresh pages each time, cleared by the kernel
       f"    pages = np.ones({HOG_BYTES}, np.uint8)\n    pages[::4096] += 1\n    del pages"]
TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")  # /proc/stat counts in these
PROGRESS_EVERY_S = 10.0
STEAL = 8  # the field of `steal` in a cpu line of /proc/stat (the name is field 0)
BUSY = ["sh", "-c", "while :; do :; done"]


def steal_ticks() -> dict[str, int]:
    """Steal of each CPU ("cpu0", ...) and their sum ("all") [ticks]. Not the kernel's "cpu" line: each line is
    rounded down to ticks on its own, so that one could miss a part of a tick that a CPU's line counts."""
    with open("/proc/stat") as stat:
        per_cpu = {row[0]: int(row[STEAL]) for row in map(str.split, stat) if re.fullmatch(r"cpu\d+", row[0])}
    return {"all": sum(per_cpu.values()), **per_cpu}


def monitor(cpu: int, seconds: float, threshold_s: float, started, out) -> None:
    """Pinned to ``cpu``: once all have ``started``, waits WAIT_S over and over for ``seconds``; sends ("late",
    late_s, steal own, steal all [ticks], t) per late wake-up, then ("done", wake-ups, seconds spent reading
    /proc/stat, refused)."""
    os.sched_setaffinity(0, {cpu})
    refused = fifo(PRIORITY)
    never, _ = os.pipe()
    wake_ups, reading_s = 0, 0.0
    started.wait()
    before, start = steal_ticks(), time.monotonic()
    while (began := time.monotonic()) < start + seconds:
        select.select([never], [], [], WAIT_S)
        woke = time.monotonic()
        after = steal_ticks()
        reading_s += time.monotonic() - woke
        wake_ups += 1
        if woke - began - WAIT_S > threshold_s:
            own = f"cpu{cpu}"
            out.send(("late", woke - began - WAIT_S, after[own] - before[own], after["all"] - before["all"],
                      woke - start))
        before = after
    out.send(("done", wake_ups, reading_s, refused))


def preemption_model() -> str:
    """The kernel's preemption model and where it was read."""
    try:
        with open("/sys/kernel/debug/sched/preempt") as current:  # "none (voluntary) full": the current in ()
            return re.search(r"\((\w+)\)", current.read()).group(1) + " (/sys/kernel/debug/sched/preempt)"
    except OSError:
        pass
    with open("/proc/cmdline") as cmdline:
        booted = re.search(r"\bpreempt=(\w+)", cmdline.read())
    if booted:
        return f"{booted.group(1)} (preempt= on the kernel command line)"
    try:
        with gzip.open("/proc/config.gz", "rt") as compressed:
            config = compressed.read()
    except OSError:
        return "unknown"
    built = re.search(r"^CONFIG_PREEMPT(_NONE|_VOLUNTARY|_LAZY|_RT|)=y", config, re.MULTILINE)
    return f"PREEMPT{built.group(1)} (build default, /proc/config.gz)" if built else "unknown"


def run(args) -> dict:
    """The monitors beside the load; per CPU its late wake-ups and totals."""
    spawn = multiprocessing.get_context("spawn")  # no fork of this process with numpy's threads
    cpus = sorted(os.sched_getaffinity(0))
    load = [subprocess.Popen(command, preexec_fn=normal_priority) for command in [BUSY] * args.busy + [HOG] * args.hog]
    started = spawn.Barrier(len(cpus) + 1)  # the run starts when every monitor is ready
    channels = {}
    for cpu in cpus:
        received, sent = spawn.Pipe(duplex=False)
        spawn.Process(target=monitor, args=(cpu, args.seconds, args.threshold_ms / 1e3, started, sent),
                      daemon=True).start()
        channels[received] = cpu
    started.wait()
    start = time.monotonic()
    results = {cpu: {"late": []} for cpu in cpus}
    shown = 0.0
    try:
        while channels:
            for channel in multiprocessing.connection.wait(list(channels), timeout=1.0):
                kind, *values = channel.recv()
                result = results[channels[channel]]
                if kind == "late":
                    result["late"].append(values)
                else:
                    result["wake_ups"], result["reading_s"], result["refused"] = values
                    del channels[channel]
            if (elapsed := time.monotonic() - start) >= shown + PROGRESS_EVERY_S:
                shown = elapsed
                late = [row for r in results.values() for row in r["late"]]
                print(f"{elapsed:5.0f}/{args.seconds:g} s: {len(late)} late wake-ups, longest "
                      f"{max((row[0] for row in late), default=0.0) * 1e3:.0f} ms, load {os.getloadavg()[0]:.1f}",
                      flush=True)
    finally:
        for process in load:
            process.kill()
            process.wait()
    return results


def summary(cpu: int, result: dict, seconds: float) -> dict:
    """One CPU's monitor: its loop rate, its late wake-ups and how many of them saw steal."""
    late = [{"late_ms": round(late_s * 1e3, 3), "steal_own_ms": round(own * TICK_S * 1e3, 3),
             "steal_all_ms": round(every * TICK_S * 1e3, 3), "t_s": round(t, 3)}
            for late_s, own, every, t in result["late"]]
    return {"cpu": cpu, "sched_fifo": f"refused: {result['refused']}" if result["refused"] else "granted",
            "wake_ups": result["wake_ups"], "wake_ups_per_s": result["wake_ups"] / seconds,
            "stat_read_mean_us": result["reading_s"] / result["wake_ups"] * 1e6,
            "late_wake_ups": len(late),
            "late_with_steal_own_cpu": sum(row["steal_own_ms"] > 0 for row in late),
            "late_with_steal_any_cpu": sum(row["steal_all_ms"] > 0 for row in late),
            "late_without_steal": sum(row["steal_all_ms"] == 0 for row in late),
            "median_late_ms": float(np.median([row["late_ms"] for row in late])) if late else None,
            "longest": max(late, key=lambda row: row["late_ms"], default=None),
            "late": late}


def plot(cpus: list[dict], threshold_ms: float, title: str) -> None:
    figure, axis = plt.subplots(figsize=(10, 4.5))
    classes = (("steal on its own CPU", "C3", lambda row: row["steal_own_ms"] > 0),
               ("steal on another CPU only", "C1", lambda row: row["steal_own_ms"] == 0 < row["steal_all_ms"]),
               ("no steal", "C0", lambda row: row["steal_all_ms"] == 0))
    for cpu, marker in zip(cpus, "os^vD"):
        for label, colour, seen in classes:
            rows = [row for row in cpu["late"] if seen(row)]
            axis.plot([row["t_s"] for row in rows], [row["late_ms"] for row in rows], marker, color=colour,
                      ls="", label=f"CPU {cpu['cpu']}, {label} ({len(rows)})")
    axis.axhline(threshold_ms, color="k", ls="--", lw=1, label=f"threshold {threshold_ms:g} ms")
    axis.set(xlabel="time [s]", ylabel="wake-up late by [ms]", title=title)
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(os.path.join(FIGURES, "host_stalls.png"), dpi=120)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0, help="run length [s] (default 300)")
    parser.add_argument("--busy", type=int, default=2, help="shell busy loops beside the monitors (default 2)")
    parser.add_argument("--hog", action=argparse.BooleanOptionalAction, default=True,
                        help="a process that allocates and touches 400 MB over and over (default on)")
    parser.add_argument("--threshold-ms", type=float, default=20.0, help="a later wake-up is logged (default 20)")
    args = parser.parse_args(argv)
    os.makedirs(FIGURES, exist_ok=True)
    steal_before = steal_ticks()
    results = run(args)
    steal_after = steal_ticks()
    cpus = [summary(cpu, result, args.seconds) for cpu, result in sorted(results.items())]
    late = [row for cpu in cpus for row in cpu["late"]]
    stolen = {name: round((steal_after[name] - ticks) * TICK_S, 3) for name, ticks in steal_before.items()}
    uname = os.uname()
    result = {
        "command": " ".join(["scripts/with_env.sh python benchmarks/host_stalls.py",
                             *(argv if argv is not None else sys.argv[1:])]),
        "settings": {"seconds": args.seconds, "busy_loops": args.busy, "memory_hog_bytes": HOG_BYTES if args.hog
                     else 0, "threshold_ms": args.threshold_ms, "wait_ms": WAIT_S * 1e3, "priority": PRIORITY,
                     "tick_s": TICK_S},
        "kernel": {"release": uname.release, "version": uname.version, "preemption": preemption_model()},
        "load_average_1min": os.getloadavg()[0],
        "steal_total_s": stolen,
        "late_wake_ups": len(late),
        "late_with_steal_own_cpu": sum(cpu["late_with_steal_own_cpu"] for cpu in cpus),
        "late_with_steal_any_cpu": sum(cpu["late_with_steal_any_cpu"] for cpu in cpus),
        "longest_late_ms": max((row["late_ms"] for row in late), default=None),
        "cpus": cpus}
    with open(os.path.join(FIGURES, "host_stalls.json"), "w") as out:
        json.dump(result, out, indent=1)
    plot(cpus, args.threshold_ms, f"SCHED_FIFO {PRIORITY} wake-ups late by > {args.threshold_ms:g} ms, "
         f"{args.busy} busy loop(s){' + 400 MB memory hog' if args.hog else ''}; steal {stolen['all']:.2f} s in all")
    print(json.dumps({k: v for k, v in result.items() if k != "cpus"}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
