"""The HV supervisor process over a simulated rig: builds the rig of ``spec["simulated"]`` (dialect, devices,
channels per device, link), then serves the supply on it as `hv_driver.server` does, with the rig's fault
injection as further requests (``inject_fault``, ``clear_faults``). The rig ends with this process.

The link (``spec["simulated"]["link"]``):
- ``memory`` (default): the supplies answer within the driver's own exchange (`sim_fallback.memory_rig`), as
  real supplies do whatever the host's load;
- ``pty``: the supplies run in a real-time process of their own on pseudo-terminals
  (`sim_fallback.hv_supply_process`), so the driver's serial path (pyserial, termios) is the one real hardware
  takes; a host that deschedules that process makes the supplies answer late.

    python -m sim_fallback.supervised --socket PATH < spec.json
"""
from hv_driver.server import announce, process_main, serve_spec

from .hv_supply_process import SimulatedSupplyProcess
from .memory_rig import MemoryRig

LINKS = {"memory": MemoryRig, "pty": SimulatedSupplyProcess}


def serve_simulated(spec: dict, path: str) -> int:
    try:
        simulated = spec["simulated"]
        link = simulated.get("link", "memory")
        if link not in LINKS:
            raise ValueError(f"link={link!r}: one of {', '.join(LINKS)}")
        # Started before the supervisor turns real-time; a pty rig takes its own priority (sim_fallback.rig).
        rig = LINKS[link](channels=simulated["channels"], dialect=spec["dialect"],
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
