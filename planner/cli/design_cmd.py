"""`python -m planner design-finger` and `design-path`: run the design optimizers from the shell.

Results go to stdout as a human summary (mm and degrees allowed) and, with --json, to a file in SI units.
Progress is printed to stderr.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import yaml

from planner import design
from planner.assembly import Assembly, Chain, PlacedBlock, save_assembly
from planner.contours import OBJECTS_CATALOG, load_mask


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
    finger.add_argument("--certify", action="store_true",
                        help="exact method: widen the search until the optimum is proven (minutes)")
    finger.add_argument("--png", type=Path, help="draw the fingers over the object into this PNG")
    finger.set_defaults(handler=run_finger)

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
    catalog = yaml.safe_load(OBJECTS_CATALOG.read_text())
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
    data = yaml.safe_load(path.read_text())
    if not isinstance(data, dict):
        raise ValueError(f"{path}: inventory must map design IDs to counts")
    return {int(k): int(v) for k, v in data.items()}


def run_finger(args) -> int:
    mask, pixel_size = _object_mask(args.object, args.pixel_size)
    result = design.design_fingers(
        mask, pixel_size, args.blocks, num_stiff_top=args.stiff_top, min_stiff_rod_diameter=args.min_stiff_diameter,
        method=args.method, time_budget=args.time_budget, seed=args.seed,
        inventory=_load_inventory(args.inventory), callback=_progress,
        options={"max_width": None} if args.certify and args.method == "exact" else None,
    )
    print(file=sys.stderr)
    report = {"success": result.success, "message": result.message, "optimal": result.optimal,
              "solve_time": result.solve_time}
    for finger in (result.left, result.right):
        report[finger.side] = {
            "design_ids": list(finger.design_ids), "cost": finger.cost, "collision": finger.collision,
            "optimal": finger.optimal, "base": finger.base.tolist(), "solve_time": finger.result.solve_time,
        }
        print(f"{finger.side:5s} IDs {list(finger.design_ids)}  cost {finger.cost:.4f} m  "
              f"base x {1e3 * finger.base[0]:.1f} mm  collision {finger.collision}  "
              f"{'certified optimal' if finger.optimal else 'not certified'}  {finger.result.solve_time:.2f} s")
    print(result.message)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    if args.png:
        _draw_fingers(result, mask, pixel_size, args.png)
    return 0 if result.success else 1


def _draw_fingers(result, mask, pixel_size, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from planner.kinematics import BLOCK_RADIUS

    fig, ax = plt.subplots(figsize=(5, 6))
    for finger, colour in ((result.left, "tab:blue"), (result.right, "tab:red")):
        ax.plot(*finger.contour.T, color="k", lw=1)
        centre = finger.centerline
        tangent = np.gradient(centre, axis=0)
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1) / np.linalg.norm(tangent, axis=1)[:, None]
        body = np.vstack([centre + BLOCK_RADIUS * normal, (centre - BLOCK_RADIUS * normal)[::-1]])
        ax.fill(*body.T, color=colour, alpha=0.2)
        ax.plot(*centre.T, color=colour, lw=1.5, label=f"{finger.side} {list(finger.design_ids)}")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.legend(fontsize=7, loc="lower center")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


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
            "cost": result.cost, "lower_bound": result.lower_bound if np.isfinite(result.lower_bound) else None,
            "solve_time": result.solve_time,
            "blocks": [{"id": i, "rotation_steps": k, "rotation": k * np.pi / 6}
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
