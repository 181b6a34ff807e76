"""`python -m planner fk`: forward kinematics of an assembly file (shape per chain, JSON and 3D plot)."""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from planner.kinematics import DEFAULT_SAMPLES_PER_BLOCK
from planner.table import DEFAULT_TABLE_PATH


def _voltage(text: str) -> tuple[str, float]:
    channel, sep, value = text.partition("=")
    try:
        volts = float(value)
    except ValueError:
        volts = math.nan
    if not sep or not channel or not math.isfinite(volts) or volts < 0:
        raise argparse.ArgumentTypeError(f"expected CHANNEL=VOLTS with VOLTS >= 0, got {text!r}")
    return channel, volts


def register(subparsers) -> None:
    parser = subparsers.add_parser("fk", help="predicted shape of an assembly (forward kinematics)")
    parser.add_argument("assembly", type=Path, help="assembly YAML (config/assemblies/*.yaml)")
    parser.add_argument(
        "--voltage", type=_voltage, action="append", default=[], metavar="CH=V",
        help="channel voltage [V]; repeat per channel; channels not given are not actuated",
    )
    parser.add_argument("--json", type=Path, help="write the shape as JSON (SI units)")
    parser.add_argument("--png", type=Path, help="draw the assembly in 3D")
    parser.add_argument("--table", type=Path, default=DEFAULT_TABLE_PATH, help="look-up table CSV (default: %(default)s)")
    parser.add_argument("--samples-per-block", type=int, default=DEFAULT_SAMPLES_PER_BLOCK, help="centerline samples per block (default: %(default)s)")
    parser.set_defaults(handler=run)


def shapes_to_dict(assembly, shapes, voltages: dict[str, float]) -> dict:
    """JSON structure of ``assembly_centerlines`` output: per chain, per block and the centerline (SI)."""
    chains = []
    for chain in assembly.chains:
        shape = shapes[chain.name]
        ends = Rotation.from_matrix(shape.rotations[1:]).as_quat()
        blocks = [
            {
                "id": block.design_id,
                "serial": block.serial,
                "theta_rad": float(shape.theta[i]),
                "rod_length_m": float(shape.length[i]),
                "phi_rad": float(shape.phi[i]),
                "valid": bool(shape.valid[i]),
                "end_position_m": shape.positions[i + 1].tolist(),
                "end_orientation_xyzw": ends[i].tolist(),
            }
            for i, block in enumerate(chain.blocks)
        ]
        chains.append(
            {
                "name": chain.name,
                "hv_channel": chain.hv_channel,
                "voltage_V": voltages.get(chain.hv_channel, 0.0),
                "base_position_m": list(chain.base_position),
                "base_orientation_xyzw": list(chain.base_orientation),
                "blocks": blocks,
                "centerline_m": shape.points.tolist(),
            }
        )
    return {"assembly": assembly.name, "frame": "assembly", "chains": chains}


def plot_assembly(assembly, shapes, path: Path) -> None:
    """3D drawing: each chain's body as a tube around its centerline, block ends marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure = plt.figure(figsize=(6.4, 5.6))
    axes = figure.add_subplot(projection="3d")
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    everything = []
    for k, chain in enumerate(assembly.chains):
        shape, colour = shapes[chain.name], colours[k % len(colours)]
        tube = shape.tube(around=16) * 1e3
        tube = np.concatenate([tube, tube[:, :1]], axis=1)  # close the circles
        axes.plot_surface(*np.moveaxis(tube, -1, 0), color=colour, alpha=0.25, linewidth=0)
        axes.plot(*(shape.points.T * 1e3), color=colour, label=chain.name)
        axes.scatter(*(shape.positions.T * 1e3), color=colour, s=10)
        everything.append(tube.reshape(-1, 3))
    points = np.concatenate(everything)
    centre, half = points.mean(axis=0), 0.5 * np.ptp(points, axis=0).max()
    axes.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half),
             zlim=(centre[2] - half, centre[2] + half), xlabel="x [mm]", ylabel="y [mm]", zlabel="z [mm]")
    axes.set_box_aspect((1, 1, 1))
    axes.set_title(assembly.name)
    axes.legend(loc="upper left", fontsize="small")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def run(args) -> int:
    from planner.assembly import load_assembly
    from planner.kinematics import assembly_centerlines
    from planner.table import load_table

    assembly = load_assembly(args.assembly)
    voltages = dict(args.voltage)
    unknown = sorted(set(voltages) - set(assembly.hv_channels))
    if unknown:
        raise ValueError(f"--voltage: assembly {assembly.name!r} has no channel {unknown}; channels: {list(assembly.hv_channels)}")
    shapes = assembly_centerlines(assembly, load_table(args.table), voltages, samples_per_block=args.samples_per_block)
    for chain in assembly.chains:
        shape = shapes[chain.name]
        print(f"{chain.name} (channel {chain.hv_channel}, {voltages.get(chain.hv_channel, 0.0):.0f} V)")
        print("  block    id  theta[deg]  L[mm]  phi[deg]  end x, y, z [mm]")
        for i, block in enumerate(chain.blocks):
            end = ", ".join(f"{1e3 * v:7.2f}" for v in shape.positions[i + 1])
            flag = "" if shape.valid[i] else "  beyond safe voltage"
            print(f"  {i + 1:5d} {block.design_id:5d} {math.degrees(shape.theta[i]):11.2f} {1e3 * shape.length[i]:6.1f}"
                  f" {math.degrees(shape.phi[i]):9.0f}  {end}{flag}")
    if args.json:
        args.json.write_text(json.dumps(shapes_to_dict(assembly, shapes, voltages), indent=1))
        print(f"wrote {args.json}")
    if args.png:
        plot_assembly(assembly, shapes, args.png)
        print(f"wrote {args.png}")
    return 0
