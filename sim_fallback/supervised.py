"""The HV supervisor process over a simulated rig: starts the rig of ``spec["simulated"]`` (dialect, devices,
channels per device), then serves the supply on its ptys as `hv_driver.server` does, with the rig's fault
injection as further requests (``inject_fault``, ``clear_faults``). The rig ends with this process.

    python -m sim_fallback.supervised --socket PATH < spec.json
"""
import argparse
import logging
import sys

from hv_driver.server import read_spec, serve_spec

from .hv_supply_process import SimulatedSupplyProcess


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim_fallback.supervised", description=__doc__.split("\n\n")[0])
    parser.add_argument("--socket", required=True, help="path of the Unix socket to serve the node on")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="[hv_supervisor] %(levelname)s %(message)s")
    try:
        spec = read_spec(sys.stdin)
        simulated = spec["simulated"]
        # Started before the supervisor turns real-time, so the rig runs at normal priority, as a device would.
        rig = SimulatedSupplyProcess(channels=simulated["channels"], dialect=spec["dialect"],
                                     devices=simulated["devices"]).start()
    except (ValueError, KeyError, TypeError, RuntimeError, OSError) as error:
        print(f"error: simulated supply: {error}", flush=True)
        return 2
    try:
        return serve_spec(spec, args.socket, rig.ports, {"inject_fault": rig.inject, "clear_faults": rig.clear_faults},
                          announce=lambda line: print(line, flush=True))
    finally:
        rig.stop()


if __name__ == "__main__":
    raise SystemExit(main())
