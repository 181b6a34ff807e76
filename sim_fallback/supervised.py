"""The HV supervisor process over a simulated rig: starts the rig of ``spec["simulated"]`` (dialect, devices,
channels per device), then serves the supply on its ptys as `hv_driver.server` does, with the rig's fault
injection as further requests (``inject_fault``, ``clear_faults``). The rig ends with this process.

    python -m sim_fallback.supervised --socket PATH < spec.json
"""
from hv_driver.server import announce, process_main, serve_spec

from .hv_supply_process import SimulatedSupplyProcess


def serve_simulated(spec: dict, path: str) -> int:
    try:
        simulated = spec["simulated"]
        # Started before the supervisor turns real-time; the rig takes its own priority (sim_fallback.rig).
        rig = SimulatedSupplyProcess(channels=simulated["channels"], dialect=spec["dialect"],
                                     devices=simulated["devices"]).start()
    except (ValueError, KeyError, TypeError, RuntimeError, OSError) as error:
        announce(f"error: simulated supply: {error}")
        return 2
    try:
        return serve_spec(spec, path, rig.ports, {"inject_fault": rig.inject, "clear_faults": rig.clear_faults})
    finally:
        rig.stop()


def main(argv=None) -> int:
    return process_main("python -m sim_fallback.supervised", __doc__.split("\n\n")[0], argv, serve_simulated)


if __name__ == "__main__":
    raise SystemExit(main())
