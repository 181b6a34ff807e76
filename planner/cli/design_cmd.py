"""`python -m planner design-finger` and `design-path`: run the design optimizers from the shell.

Results go to stdout as a human summary (mm and degrees allowed) and, with --json, to a file in SI units.
Progress is printed to stderr.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from planner import design
from planner.assembly import ROTATION_STEP, Assembly, Chain, PlacedBlock, save_assembly
from planner.bounded_yaml import load_yaml_file
from planner.contours import OBJECTS_CATALOG, extract_contours, load_mask


def register(subparsers) -> None:
    finger = subparsers.add_parser("design-finger", help="design left/right fingers conforming to an object image")
    finger.add_argument("object", help="image file, or a sample object name from config/objects/objects.yaml")
    finger.add_argument("--pixel-size", type=float, help="image scale [m/pixel] (default: the catalogue's)")
    finger.add_argument("--blocks", type=int, required=True, help="blocks per finger")
    finger.add_argument("--stiff-top", type=int, default=0, help="top blocks forced stiff (default 0)")
    finger.add_argument("--min-stiff-diameter", type=float, default=design.DEFAULT_MIN_STIFF_ROD_DIAMETER,
                        help="rod diameter a stiff block needs [m] (default %(default)s)")
    _common(finger)
    finger.add_argument("--inventory", type=Path, help="YAML mapping design ID -> blocks on the shelf")
    finger.add_argument("--contact-tolerance", type=float, default=0.0,
                        help="how far a finger body may enter the object before it collides [m] (default 0)")
    finger.add_argument("--png", type=Path, help="draw the fingers over the object into this PNG")
    finger.set_defaults(handler=run_finger)

    prepare = subparsers.add_parser("prepare-design", help="compile the finger search and build its lookahead "
                                    "fields for the usual block counts (set-up runs this once)")
    prepare.set_defaults(handler=run_prepare)

    path = subparsers.add_parser("design-path", help="design a chain (with rotations) following a 3D path")
    path.add_argument("points", type=Path, help="CSV of x,y,z [m] per line, base first (header line allowed)")
    path.add_argument("--blocks", type=int, required=True, help="blocks in the chain")
    path.add_argument("--no-rotation", action="store_true", help="keep the chain planar (all rotations 0)")
    _common(path)
    path.add_argument("--yaml", type=Path, help="write the chain as an assembly YAML")
    path.set_defaults(handler=run_path)


def _common(parser) -> None:
    parser.add_argument("--method", choices=design.METHODS, default="exact")
    parser.add_argument("--seed", type=int, default=0, help="PSO seed (default 0)")
    parser.add_argument("--time-budget", type=float, help="[s] (default: none)")
    parser.add_argument("--json", type=Path, help="write the result as JSON (SI units)")


def _progress(progress) -> None:
    print(f"\r  {100 * progress.fraction:5.1f} %  best {progress.best_cost:.6g} m  "
          f"{progress.nfev} evaluations  {progress.elapsed:.1f} s", end="", file=sys.stderr, flush=True)


def _object_mask(name: str, pixel_size: float | None):
    catalog = load_yaml_file(OBJECTS_CATALOG)
    if name in catalog:
        entry = catalog[name]
        scale = float(entry["pixel_size_m"]) if pixel_size is None else pixel_size  # 0 is an error, not "default"
        return load_mask(OBJECTS_CATALOG.parent / entry["file"]), scale
    if pixel_size is None:
        raise ValueError(f"--pixel-size is needed for an image file ({name!r} is not a sample object)")
    return load_mask(Path(name)), pixel_size


def _load_inventory(path: Path | None) -> dict[int, int] | None:
    if path is None:
        return None
    data = load_yaml_file(path)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: inventory must map design IDs to counts")
    return {int(k): int(v) for k, v in data.items()}


def run_finger(args) -> int:
    mask, pixel_size = _object_mask(args.object, args.pixel_size)
    result = design.design_fingers(
        mask, pixel_size, args.blocks, num_stiff_top=args.stiff_top, min_stiff_rod_diameter=args.min_stiff_diameter,
        method=args.method, time_budget=args.time_budget, seed=args.seed,
        inventory=_load_inventory(args.inventory), callback=_progress, contact_tolerance_m=args.contact_tolerance,
    )
    print(file=sys.stderr)
    report = {"success": result.success, "message": result.message, "optimal": result.optimal,
              "solve_time_s": result.solve_time, "contact_tolerance_m": args.contact_tolerance,
              "frame": "object frame: origin at the top centre of the object's bounding box, x right, z up [m]"}
    for finger in (result.left, result.right):
        report[finger.side] = {
            "design_ids": list(finger.design_ids), "cost_m": finger.cost, "collision": finger.collision,
            "min_clearance_m": finger.min_clearance_m, "optimal": finger.optimal,
            "lower_bound_m": finger.lower_bound_m if np.isfinite(finger.lower_bound_m) else None,
            "base_m": finger.base.tolist(), "centerline_m": finger.centerline.tolist(),
            "solve_time_s": finger.result.solve_time,
        }
        bound = "certified optimal" if finger.optimal else f"not certified (lower bound {finger.lower_bound_m:.4f} m)"
        print(f"{finger.side:5s} IDs {list(finger.design_ids)}  cost {finger.cost:.4f} m  "
              f"base x {1e3 * finger.base[0]:.1f} mm  clearance {1e3 * finger.min_clearance_m:.3f} mm  "
              f"collision {finger.collision}  {bound}  {finger.result.solve_time:.2f} s")
    print(result.message)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    if args.png:
        from planner.finger_plot import plot_designed_fingers  # matplotlib only when drawing

        plot_designed_fingers(result, extract_contours(mask, pixel_size), args.png)
    return 0 if result.success else 1


def run_prepare(args) -> int:
    started = time.perf_counter()
    print(f"preparing the finger search for (blocks, stiff top) {list(design.PREPARED_CONFIGURATIONS)} ...",
          file=sys.stderr, flush=True)
    design.prepare_finger_search(progress=lambda line: print(f"  {line}", file=sys.stderr, flush=True))
    print(f"finger search ready ({time.perf_counter() - started:.1f} s)", file=sys.stderr)
    return 0


def run_path(args) -> int:
    points = np.loadtxt(args.points, delimiter=",", ndmin=2, comments="#", skiprows=_header_rows(args.points))
    result = design.design_path(points, args.blocks, allow_rotation=not args.no_rotation, method=args.method,
                                time_budget=args.time_budget, seed=args.seed, callback=_progress)
    print(file=sys.stderr)
    print(f"IDs {list(result.design_ids)}\nrotation steps {list(result.rotation_steps)}\n"
          f"cost {result.cost:.5f} m  {result.solve_time:.2f} s\n{result.message}")
    chain = Chain("path", "path", tuple(PlacedBlock(i, k) for i, k in zip(result.design_ids, result.rotation_steps)))
    if args.yaml:
        save_assembly(Assembly("designed_path", (chain,)), args.yaml)
    if args.json:
        args.json.write_text(json.dumps({
            "success": result.success, "message": result.message, "optimal": result.optimal,
            "cost_m": result.cost, "lower_bound_m": result.lower_bound if np.isfinite(result.lower_bound) else None,
            "solve_time_s": result.solve_time,
            "blocks": [{"id": i, "rotation_steps": k, "rotation_rad": k * ROTATION_STEP}
                       for i, k in zip(result.design_ids, result.rotation_steps)],
        }, indent=2))
    return 0 if result.success else 1


def _header_rows(path: Path) -> int:
    first = path.read_text().splitlines()[0] if path.exists() else ""
    try:
        [float(v) for v in first.split(",")]
        return 0
    except ValueError:
        return 1
