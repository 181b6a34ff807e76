"""``python -m estimation``: estimate a chain from an image, calibrate its blocks, render a test image."""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import yaml

from estimation.view import ImagePose
from planner.table import DEFAULT_TABLE_PATH

CALIBRATION_HEADER = """\
# Per-block calibration (planner/block_calibration.py): for each physical block, by serial, its
# design ID and the offset [rad] added to the design's model angle. Written by
# `python -m estimation calibrate` from images of the chain at rest and actuated.
"""


def _block_offset(text: str) -> tuple[int, float]:
    block, sep, value = text.partition("=")
    try:
        return int(block), math.radians(float(value))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected BLOCK=DEGREES (block counted from 1 at the base), got {text!r}") from None


def _add_chain_arguments(parser, image_plane: bool = True) -> None:
    parser.add_argument("--assembly", type=Path, required=True, help="assembly YAML with the chain as believed built")
    parser.add_argument("--chain", help="chain name (default: the assembly's only chain)")
    parser.add_argument("--pixel-size", type=float, required=True, help="[m / pixel]")
    parser.add_argument("--table", type=Path, default=DEFAULT_TABLE_PATH, help="look-up table CSV (default: %(default)s)")
    if image_plane:
        parser.add_argument("--base", type=float, nargs=3, required=True, metavar=("X", "Y", "ANGLE"),
                            help="base centre in the image [m] (origin top-left, y down) and growth direction [rad]")
        parser.add_argument("--mirrored", action="store_true", help="the chain's +x lies 90 deg counter-clockwise of its growth axis")
        parser.add_argument("--threshold", type=float, help="grey level above which a pixel is the chain (grey images)")
        parser.add_argument("--calibration", type=Path, help="block calibration YAML the blocks' angles are expected from")


def register(subparsers) -> None:
    estimate = subparsers.add_parser("estimate", help="block angles and assembly mistakes from a side-view image")
    estimate.add_argument("image", type=Path)
    _add_chain_arguments(estimate)
    estimate.add_argument("--voltage", type=float, default=0.0, help="voltage on the chain's channel [V] (default 0)")
    estimate.add_argument("--json", type=Path, help="write the result as JSON (SI units)")
    estimate.add_argument("--png", type=Path, help="draw the image with the predicted and fitted outlines")
    estimate.set_defaults(handler=run_estimate)

    calibrate = subparsers.add_parser("calibrate", help="per-block angle offsets from images at known voltages")
    calibrate.add_argument("--image", nargs=2, action="append", required=True, metavar=("IMAGE", "VOLTS"),
                           help="an image and the voltage on the chain's channel [V]; repeat per image")
    _add_chain_arguments(calibrate)
    calibrate.add_argument("--write", type=Path, help="calibration YAML to update (other blocks' entries are kept)")
    calibrate.set_defaults(handler=run_calibrate)

    render = subparsers.add_parser("render", help="synthetic side-view image of a chain (reference renderer)")
    _add_chain_arguments(render, image_plane=False)
    render.add_argument("--voltage", type=float, default=0.0, help="[V] (default 0)")
    render.add_argument("--offset", type=_block_offset, action="append", default=[], metavar="BLOCK=DEG",
                        help="add an angle offset to a block (counted from 1); repeat per block")
    render.add_argument("--angle", type=float, default=math.pi / 2, help="growth direction in the image [rad] (default: down)")
    render.add_argument("--mirrored", action="store_true")
    render.add_argument("--frame", type=float, nargs=4, metavar=("X", "Y", "COLUMNS", "ROWS"),
                        help="base position [m] and image size [pixels] (default: fitted around the chain)")
    render.add_argument("--out", type=Path, required=True, help="PNG to write")
    render.set_defaults(handler=run_render)


def _load(args):
    from planner.assembly import load_assembly
    from planner.table import load_table

    assembly = load_assembly(args.assembly)
    if args.chain is None:
        if len(assembly.chains) != 1:
            raise ValueError(f"assembly {assembly.name!r} has chains {[c.name for c in assembly.chains]}; choose one with --chain")
        chain = assembly.chains[0]
    else:
        try:
            chain = assembly.chain(args.chain)
        except KeyError as error:
            raise ValueError(error.args[0]) from None
    return chain, load_table(args.table)


def _volts(text: str) -> float:
    try:
        volts = float(text)
    except ValueError:
        volts = math.nan
    if not (math.isfinite(volts) and volts >= 0):
        raise ValueError(f"--image: the voltage must be a number >= 0 V, got {text!r}")
    return volts


def _pose(args) -> ImagePose:
    return ImagePose(*args.base, mirrored=args.mirrored)


def run_estimate(args) -> int:
    from estimation.estimate import estimate_chain
    from planner.block_calibration import load_block_calibration

    chain, table = _load(args)
    calibration = load_block_calibration(args.calibration) if args.calibration else None
    result = estimate_chain(args.image, chain, args.pixel_size, _pose(args), voltage=args.voltage,
                            calibration=calibration, table=table, threshold=args.threshold)
    print(f"{chain.name}: {result.message}")
    print("  block    id  step  theta[deg]  +-[deg]  predicted[deg]  residual before/after fit [mm]")
    for b in result.blocks:
        print(f"  {b.position + 1:5d} {b.design_id:5d} {b.rotation_steps:5d} {math.degrees(b.theta):11.2f} "
              f"{math.degrees(b.theta_std):8.2f} {math.degrees(b.predicted_theta):15.2f}   "
              f"{1e3 * b.residual_predicted:6.2f} / {1e3 * b.residual:5.2f}")
    print(f"  unexplained outline {1e3 * result.unexplained_length:.1f} of {1e3 * result.outline_length:.0f} mm; "
          f"{result.hypotheses} chains fitted in {1e3 * result.solve_time:.0f} ms")
    if args.json:
        args.json.write_text(json.dumps(result.to_dict(), indent=1))
        print(f"wrote {args.json}")
    if args.png:
        plot_estimate(args.image, result, _pose(args), args.pixel_size, table, args.png)
        print(f"wrote {args.png}")
    return 0 if result.as_built else 1


def run_calibrate(args) -> int:
    from estimation.calibrate import calibrate_chain
    from planner.block_calibration import load_block_calibration

    chain, table = _load(args)
    calibration = load_block_calibration(args.calibration) if args.calibration else None
    images = [(Path(path), _volts(volts)) for path, volts in args.image]
    result = calibrate_chain(images, chain, args.pixel_size, _pose(args), table=table, threshold=args.threshold,
                             calibration=calibration)
    print(result.message)
    print("  block  serial        id  offset[deg]  +-[deg]  per image [deg]")
    for k, b in enumerate(result.blocks):
        seen = ", ".join(f"{math.degrees(o):.2f}" for o in b.per_image)
        print(f"  {k + 1:5d}  {b.serial:12s} {b.design_id:3d} {math.degrees(b.offset):12.2f} {math.degrees(b.offset_std):8.2f}  {seen}")
    existing = load_block_calibration(args.write) if args.write else None
    text = CALIBRATION_HEADER + yaml.safe_dump(result.document(existing), sort_keys=False)
    if args.write:
        args.write.write_text(text)
        print(f"wrote {args.write}")
    else:
        print(text, end="")
    return 0 if result.success else 1


def run_render(args) -> int:
    from PIL import Image

    from estimation.render import render_chain, to_binary

    chain, table = _load(args)
    offsets = np.zeros(len(chain.blocks))
    for block, offset in args.offset:
        if not 1 <= block <= len(offsets):
            raise ValueError(f"--offset: block {block} is not in 1..{len(offsets)}")
        offsets[block - 1] += offset
    frame = None
    if args.frame:
        x, y, columns, rows = args.frame
        frame = (ImagePose(x, y, args.angle, args.mirrored), (int(rows), int(columns)))
    steps = [b.rotation_steps for b in chain.blocks]
    coverage, pose, _ = render_chain(chain.design_ids, steps, table, args.pixel_size, offsets=offsets,
                                     voltage=args.voltage, angle=args.angle, mirrored=args.mirrored, frame=frame)
    Image.fromarray(to_binary(coverage)).save(args.out)
    mirrored = " --mirrored" if args.mirrored else ""
    rows, columns = coverage.shape
    print(f"wrote {args.out} ({columns} x {rows} pixels); base: --base {pose.x:.6f} {pose.y:.6f} {pose.angle:.6f}{mirrored}")
    return 0


def plot_estimate(image, result, pose: ImagePose, pixel_size: float, table, path: Path) -> None:
    """The image with the table's predicted outline (dashed) and the fitted outline of the chain found."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from estimation.outline import outline_layout, outline_points
    from estimation.silhouette import read_image
    from planner.kinematics import chain_blocks

    grey = read_image(image)
    _, length, phi, _ = chain_blocks(result.chain, table)
    layout = outline_layout(length, phi, pixel_size)
    fitted = pose.corrected(result.base_shift, result.base_turn)
    rows, columns = grey.shape
    figure, axes = plt.subplots(figsize=(6.4, 6.4 * rows / columns + 0.6))
    axes.imshow(grey, cmap="gray", extent=(0, 1e3 * columns * pixel_size, 1e3 * rows * pixel_size, 0))
    for angles, where, style, label in ((np.array([b.predicted_theta for b in result.blocks]), pose, "--", "predicted (table)"),
                                        (result.theta, fitted, "-", "fitted")):
        points = 1e3 * where.to_image(outline_points(layout, angles))
        for k, part in enumerate(layout.polylines):
            axes.plot(*points[part].T, style, color="tab:orange" if style == "--" else "tab:cyan", lw=1.2,
                      label=label if k == 0 else None)
    axes.set(xlabel="x [mm]", ylabel="y [mm]", title=result.message if len(result.message) < 70 else result.message[:67] + "...")
    axes.legend(loc="best", fontsize="small")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m estimation", description="Block angles and assembly mistakes from side-view images.")
    register(parser.add_subparsers(dest="command", required=True, metavar="COMMAND"))
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args) or 0)
    except (ValueError, FileNotFoundError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
