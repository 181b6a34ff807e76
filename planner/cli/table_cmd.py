"""`python -m planner table`: regenerate config/block_table.csv from the block model."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from planner.atomic_file import check_writable_target
from planner.block_model import TABLE_FIDELITY, Fidelity
from planner.table import DEFAULT_TABLE_PATH


def register(subparsers) -> None:
    parser = subparsers.add_parser("table", help="regenerate the 84-design look-up table from the block model")
    parser.add_argument("--out", type=Path, default=DEFAULT_TABLE_PATH, help="CSV to write (default: %(default)s)")
    parser.add_argument(
        "--strips", type=int, default=TABLE_FIDELITY.n_strips, help="membrane strips (default: %(default)s)"
    )
    parser.set_defaults(handler=run)


def run(args) -> int:
    from planner.table_builder import build_table

    check_writable_target(args.out)  # before the build, not after it
    start = time.perf_counter()
    table = build_table(fidelity=Fidelity(TABLE_FIDELITY.kind, args.strips))
    path = table.write_csv(args.out)
    elapsed = time.perf_counter() - start
    theta0 = np.degrees(table.theta0)
    print(
        f"wrote {path} ({len(table.ids)} designs, {len(table.voltages)} voltages) in {elapsed:.2f} s\n"
        f"theta0 {np.nanmin(theta0):.1f}..{np.nanmax(theta0):.1f} deg, "
        f"safe voltage {table.safe_voltage.min():.0f}..{table.safe_voltage.max():.0f} V, "
        f"mass {1e3 * table.mass.min():.2f}..{1e3 * table.mass.max():.2f} g"
    )
    return 0
