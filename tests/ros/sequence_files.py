"""The shipped sequences with their timings scaled down for tests (faster arm, steeper ramps, fewer cycles)."""
from pathlib import Path

import yaml

SEQUENCES = Path(__file__).resolve().parents[2] / "config" / "sequences"
SCALED_KEYS = ("speed", "slew_rate", "cycles")


def scaled(name: str, directory: Path, speed: float, slew_rate: float = 100_000.0, cycles: int = 2) -> str:
    """Write config/sequences/<name>.yaml into ``directory`` with every speed, slew rate and cycle count
    (defaults and steps) replaced; returns the name, for a sequencer whose ``sequences_dir`` is ``directory``."""
    values = {"speed": speed, "slew_rate": slew_rate, "cycles": cycles}

    def rewrite(node):
        if isinstance(node, dict):
            return {key: values[key] if key in SCALED_KEYS else rewrite(value) for key, value in node.items()}
        return [rewrite(item) for item in node] if isinstance(node, list) else node

    document = rewrite(yaml.safe_load((SEQUENCES / f"{name}.yaml").read_text()))
    document["defaults"] = {**document.get("defaults", {}), "speed": speed, "slew_rate": slew_rate}
    (directory / f"{name}.yaml").write_text(yaml.safe_dump(document))
    return name
