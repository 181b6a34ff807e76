#!/usr/bin/env bash
# Every benchmark of the README, one after the other (`make bench`). Each writes JSON + PNG into
# docs/figures/. Run inside the project environment (scripts/with_env.sh). Takes about 65-75 minutes
# (two_hosts.py: about 20, root only).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
benchmarks=(
    block_model_fidelity.py
    block_table_overview.py
    block_model_loo.py
    ogden_fit.py
    kinematics_throughput.py
    image_estimation.py
    finger_optimizers.py
    gripper_design.py
    path_optimizers.py
    reconfiguration.py
    hv_loop.py
    hv_ramp.py
    hv_fault_bounds.py
    recorder_load.py
    ros_nodes.py
    node_cpu.py
    sequencer_gait.py
    publish_hold.py
    mcap_open.py
    host_stalls.py
)
for i in "${!benchmarks[@]}"; do
    printf '\n=== [%d/%d] benchmarks/%s ===\n' "$((i + 1))" "${#benchmarks[@]}" "${benchmarks[$i]}"
    python "benchmarks/${benchmarks[$i]}"
done
# Two emulated hosts (network namespaces, TAP devices) need root.
printf '\n=== benchmarks/two_hosts.py ===\n'
if [ "$(id -u)" -eq 0 ]; then python benchmarks/two_hosts.py; else echo "skipped: needs root"; fi
