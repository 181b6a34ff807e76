#!/usr/bin/env bash
# Fresh-clone stress test: clone this repository's committed HEAD into an empty temporary folder N times and
# run the CI command there (`.ci/run`: set-up + `make test`), or `make demo` with --demo, optionally with K busy
# loops (--busy K) running beside each run. Reports how many runs passed and keeps the log of every failed run.
#
#   scripts/stress_ci.sh 10              # 10 CI runs, one after the other
#   scripts/stress_ci.sh 3 --busy 2      # the same with two busy loops beside each run
#   scripts/stress_ci.sh 5 --demo        # `make demo` instead of .ci/run
#
# Results go to out/stress/<time>/ (or --results DIR): run-<i>.log of each failed run (and the demo's
# stack.log) and summary.json of all runs. A run that does not end within --timeout seconds (default 3600)
# is killed and counts as failed. ROS_DOMAIN_ID and SOFTBLOCK_TEST_DOMAINS are passed on to the runs; the runs'
# test domains default to 100-199, so a suite run by hand beside the series (10-99) never reaches their nodes.
set -euo pipefail
export SOFTBLOCK_TEST_DOMAINS="${SOFTBLOCK_TEST_DOMAINS:-100-199}"
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

usage() { echo "usage: $0 N [--busy K] [--demo] [--timeout SECONDS] [--results DIR]" >&2; exit 2; }
[[ $# -ge 1 && $1 =~ ^[1-9][0-9]*$ ]] || usage
runs=$1
shift
busy=0 demo=false timeout_s=3600 results="$repo/out/stress/$(date -u +%Y%m%dT%H%M%SZ)"
while [[ $# -gt 0 ]]; do
    case $1 in
        --busy) [[ ${2:-} =~ ^(0|[1-9][0-9]*)$ ]] || usage; busy=$2; shift ;;
        --demo) demo=true ;;
        --timeout) [[ ${2:-} =~ ^[1-9][0-9]*$ ]] || usage; timeout_s=$2; shift ;;
        --results) [[ -n ${2:-} ]] || usage; results=$2; shift ;;
        *) usage ;;
    esac
    shift
done
if $demo; then command=(make demo); else command=(.ci/run); fi
commit="$(git -C "$repo" rev-parse HEAD)"
[[ -z "$(git -C "$repo" status --porcelain --untracked-files=no)" ]] ||
    echo "[stress] note: uncommitted changes are not in the clones; testing commit $commit" >&2
mkdir -p "$results"
table="$results/runs.tsv"
: >"$table"

kill_leftovers() {
    # A killed run can leave processes whose parent died first (the launcher's nodes sit in their own
    # process groups). Each was started from the clone's venv, so its command line names the clone folder.
    local pids=() proc
    for proc in /proc/[0-9]*; do
        { tr '\0' ' ' <"$proc/cmdline"; } 2>/dev/null | grep -qF "$1/" && pids+=("${proc#/proc/}")
    done
    if ((${#pids[@]})); then
        echo "[stress] killing ${#pids[@]} process(es) the run left behind" >&2
        kill -KILL "${pids[@]}" 2>/dev/null || true
    fi
}

busy_pids=() workdir=""
cleanup() {
    if ((${#busy_pids[@]})); then kill "${busy_pids[@]}" 2>/dev/null || true; fi
    if [[ -n $workdir ]]; then kill_leftovers "$workdir"; rm -rf "$workdir"; fi
}
trap cleanup EXIT
trap 'exit 130' INT TERM
for ((k = 0; k < busy; k++)); do
    python3 -c 'while True: pass' &  # one core's worth of competing load each, as another CI job would add
    busy_pids+=($!)
done

passed=0
for ((i = 1; i <= runs; i++)); do
    workdir="$(mktemp -d "${TMPDIR:-/tmp}/softblock-stress.XXXXXX")"
    printf '[stress] run %d/%d: %s in a fresh clone of %.12s ... ' "$i" "$runs" "${command[*]}" "$commit" >&2
    start=$SECONDS
    status=0
    (
        git clone --quiet --no-hardlinks "$repo" "$workdir/clone"
        cd "$workdir/clone"
        git checkout --quiet "$commit"
        exec timeout --kill-after=60 "$timeout_s" "${command[@]}"
    ) >"$workdir/run.log" 2>&1 || status=$?
    seconds=$((SECONDS - start))
    kill_leftovers "$workdir"
    log=""
    if [[ $status == 0 ]]; then
        passed=$((passed + 1))
        echo "passed (${seconds} s)" >&2
    else
        log="$results/run-$i.log"
        cp "$workdir/run.log" "$log"
        if [[ -f $workdir/clone/out/demo/stack.log ]]; then cp "$workdir/clone/out/demo/stack.log" "$results/run-$i.stack.log"; fi
        echo "FAILED with status $status (${seconds} s): $log" >&2
    fi
    printf '%d\t%d\t%d\t%s\n' "$i" "$status" "$seconds" "$log" >>"$table"
    rm -rf "$workdir"
    workdir=""
done

python3 - "$table" "$results/summary.json" "$commit" "${command[*]}" "$busy" <<'EOF'
import json, os, sys
table, out, commit, command, busy = sys.argv[1:]
runs = [dict(zip(("run", "status", "seconds", "log"), line.rstrip("\n").split("\t"))) for line in open(table)]
runs = [{"run": int(r["run"]), "passed": r["status"] == "0", "status": int(r["status"]),
         "seconds": int(r["seconds"]), "log": r["log"] or None} for r in runs]
summary = {"commit": commit, "command": command, "busy_loops": int(busy), "runs": len(runs),
           "passed": sum(r["passed"] for r in runs), "cpus": os.cpu_count(),
           "load_average_at_end": os.getloadavg(), "results": runs}
json.dump(summary, open(out, "w"), indent=2)
EOF
rm "$table"
echo "[stress] ${command[*]}: $passed of $runs passed with $busy busy loop(s); results in $results" >&2
[[ $passed == "$runs" ]]
