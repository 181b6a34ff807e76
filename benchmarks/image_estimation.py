"""Image estimation: angle accuracy, mistake recovery and time per image on synthetic side views.

Chains of 2-8 random table designs (planar, every block with a random angle offset) are drawn by the
reference renderer (estimation.render, independent of the estimator's forward model) with a random
growth direction and mirror state, then estimated with estimation.estimate_chain given the believed
chain. Four studies:

  resolution  as-built chains at 0.1-1 mm/px: angle errors and false alarms
  faults      at 0.25 mm/px: pixel noise, blur, grey noise, an occluded tip
  mistakes    at 0.25 and 0.4 mm/px: one wrong design, wrong rotation (flip or out of plane), missing or extra
              block, each with the shape difference it makes (Hausdorff distance between the believed
              and the built chain's silhouettes, same angles) in pixels
  time        CPU time per image against the number of blocks (one core)
  candidates  at 0.4 mm/px: mistakes found and time per image against the candidates refined

Writes docs/figures/image_estimation.json and .png (--quick: a smoke run into out/benchmarks/; --only STUDY
reruns one study into the JSON; --replot redraws the figure). Each study draws from its own seeded stream.
    scripts/with_env.sh python benchmarks/image_estimation.py [--quick] [--seed 0] [--only time] [--cases N]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy import ndimage  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # this checkout's packages, not an installed copy
from estimation.estimate import estimate_chain  # noqa: E402
from estimation.hypotheses import MistakeKind, rotation_class  # noqa: E402
from estimation.render import (  # noqa: E402
    blurred,
    render_chain,
    to_binary,
    with_grey_noise,
    with_pixel_noise,
)
from planner.assembly import Chain, PlacedBlock  # noqa: E402
from planner.table import load_table  # noqa: E402

FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"
QUICK_OUTPUT = Path(__file__).resolve().parent.parent / "out" / "benchmarks"
PIXEL = 0.25e-3
OFFSET_DEG = 5.0  # as-built angle offsets: uniform in +-this per block
MISTAKE_OFFSET_DEG = 2.5  # offsets in the mistake study (the paper's calibration range)


def chain_of(ids, steps=None) -> Chain:
    steps = steps if steps is not None else [0] * len(ids)
    return Chain("bench", "main", tuple(PlacedBlock(int(i), int(k)) for i, k in zip(ids, steps)))


def draw(table, ids, steps, offsets, pixel_size, rng, frame=None):
    coverage, pose, theta = render_chain(ids, steps, table, pixel_size, offsets=offsets, angle=rng.uniform(0, 2 * np.pi),
                                         mirrored=bool(rng.integers(2)), frame=frame)
    return coverage, pose, theta


def timed(image, chain, pose, table, pixel_size, threshold=None, occlusion=None):
    started = time.process_time()
    result = estimate_chain(image, chain, pixel_size, pose, table=table, threshold=threshold, occlusion=occlusion)
    return result, time.process_time() - started


def angle_errors(result, theta, visible=None) -> list[float]:
    if len(result.blocks) != len(theta):
        return []
    errors = np.degrees(result.theta - theta)
    return [float(e) for e in (errors if visible is None else errors[:visible])]


# ------------------------------------------------------------------------------------------ studies
def resolution_study(table, rng, cases: int, sizes) -> dict:
    rows = []
    for size in sizes:
        errors, alarms, times, z = [], 0, [], []
        for case in range(cases):
            ids = rng.choice(table.ids, rng.integers(2, 9))
            offsets = np.radians(rng.uniform(-OFFSET_DEG, OFFSET_DEG, len(ids)))
            coverage, pose, theta = draw(table, ids, None, offsets, size, rng)
            result, cpu = timed(to_binary(coverage), chain_of(ids), pose, table, size)
            errors += angle_errors(result, theta)
            if len(result.blocks) == len(theta):
                z += list(np.abs(result.theta - theta) / result.theta_std)
            alarms += not result.as_built
            times.append(cpu)
            print(f"  resolution {1e3 * size:.2f} mm/px: {case + 1}/{cases}", end="\r", flush=True)
        print()
        rows.append(_error_summary(errors) | {
            "pixel_size_m": size, "cases": cases, "false_alarms": alarms, "median_cpu_s": float(np.median(times)),
            "within_2_sigma": float(np.mean(np.array(z) <= 2.0)) if z else None, "errors_deg": errors,
        })
    return {"rows": rows}


def _error_summary(errors) -> dict:
    absolute = np.abs(errors) if errors else np.array([np.nan])
    return {"median_abs_error_deg": float(np.median(absolute)), "p95_abs_error_deg": float(np.percentile(absolute, 95)),
            "max_abs_error_deg": float(np.max(absolute)), "within_0_5_deg": float(np.mean(absolute <= 0.5))}


def fault_study(table, rng, cases: int) -> dict:
    faults = {
        "clean": lambda c, r: (to_binary(c), None),
        "pixel noise 1%": lambda c, r: (with_pixel_noise(to_binary(c), 0.01, r), None),
        "pixel noise 5%": lambda c, r: (with_pixel_noise(to_binary(c), 0.05, r), None),
        "blur 1 px": lambda c, r: (to_binary(blurred(c, 1.0)), None),
        "blur 2 px + grey": lambda c, r: (np.round(255 * blurred(c, 2.0)).astype(np.uint8), 127.5),
        "grey noise 10%": lambda c, r: (with_grey_noise(c, 0.1, r), 127.5),
    }
    rows = []
    occluders = {"occluded tip, round occluder": "disc", "occluded tip, straight edge": "edge",
                 "occluded tip, straight edge given": "edge given"}
    for name, fault in list(faults.items()) + list(occluders.items()):
        errors, as_built, times = [], 0, []
        for case in range(cases):
            ids = rng.choice(table.ids, rng.integers(2, 9))
            offsets = np.radians(rng.uniform(-OFFSET_DEG, OFFSET_DEG, len(ids)))
            coverage, pose, theta = draw(table, ids, None, offsets, PIXEL, rng)
            visible, occlusion, threshold = None, None, None
            if isinstance(fault, str):
                image, hidden = _occlude_tip(coverage, pose, ids, theta, table, rng, fault)
                occlusion = hidden if fault == "edge given" else None
                visible = len(ids) - 1  # angle errors of the blocks before the last
            else:
                image, threshold = fault(coverage, rng)
            try:
                result, cpu = timed(image, chain_of(ids), pose, table, PIXEL, threshold, occlusion)
            except ValueError as error:  # e.g. noise split the silhouette: counted as a failure
                print(f"\n  {name}: {error}")
                continue
            errors += angle_errors(result, theta, visible)
            as_built += result.as_built
            times.append(cpu)
            print(f"  {name}: {case + 1}/{cases}", end="\r", flush=True)
        print()
        rows.append(_error_summary(errors) | {"fault": name, "cases": cases, "as_built": as_built,
                                              "median_cpu_s": float(np.median(times)) if times else None})
    return {"rows": rows}


def _occlude_tip(coverage, pose, ids, theta, table, rng, shape: str):
    """The image with part of the last block hidden, and the hidden pixels. ``disc``: a disc of one block
    radius near the tip; ``edge``/``edge given``: an occluder with a straight edge across the last block,
    3-10 mm from the tip, at a random angle within +-45 deg of square to the block's axis, covering the
    tip out to two block radii (so it never reaches back to the rest of a curled chain)."""
    from estimation.render import cross_section_frames

    rows = table.index_of(ids)
    end = cross_section_frames(theta, np.asarray(table.rod_length)[rows], np.zeros(len(ids)))[-1]
    tip = pose.to_image(end[[0, 2], 3]) / PIXEL
    columns, rows_ = np.meshgrid(np.arange(coverage.shape[1]) + 0.5, np.arange(coverage.shape[0]) + 0.5)
    if shape == "disc":
        centre = tip + rng.normal(0, 10, 2)
        hidden = (columns - centre[0]) ** 2 + (rows_ - centre[1]) ** 2 <= (12.5e-3 / PIXEL) ** 2
    else:
        axis = pose.directions_to_image(end[[0, 2], 2])  # the tip's axis in the image
        cut = tip - axis * rng.uniform(3e-3, 10e-3) / PIXEL
        tilt = rng.uniform(-np.pi / 4, np.pi / 4)
        normal = np.array([[np.cos(tilt), -np.sin(tilt)], [np.sin(tilt), np.cos(tilt)]]) @ axis
        near_tip = (columns - tip[0]) ** 2 + (rows_ - tip[1]) ** 2 <= (25e-3 / PIXEL) ** 2
        hidden = near_tip & ((columns - cut[0]) * normal[0] + (rows_ - cut[1]) * normal[1] > 0)
    return np.where(hidden, 0, to_binary(coverage)).astype(np.uint8), hidden


def _mistake(kind: str, ids, steps, rng, table):
    """The chain actually built for a believed (ids, steps), and the believed index of the mistake."""
    ids, steps = list(ids), list(steps)
    k = int(rng.integers(len(ids)))
    if kind == "wrong design":
        ids[k] = int(rng.choice([i for i in table.ids if i != ids[k]]))
    elif kind == "flip (180 deg)":
        steps[k] = (steps[k] + 6) % 12
    elif kind == "out of plane":
        steps[k] = int(rng.choice([1, 2, 3, 4, 5, 7, 8, 9, 10, 11]))
    elif kind == "missing block":
        del ids[k], steps[k]
    elif kind == "extra block":
        k = int(rng.integers(len(ids) + 1))
        ids.insert(k, int(rng.choice(table.ids)))
        steps.insert(k, 0)
    return ids, steps, k


def _hausdorff_px(table, first, second, pixel_size) -> float:
    """Hausdorff distance [pixels] between the side views of two chains ((ids, steps, offsets)) on one base."""
    from estimation.render import render_silhouette
    from estimation.view import ImagePose

    shapes = []
    for ids, steps, offsets in (first, second):
        theta, _ = table.angle_at(ids, 0.0)
        length = np.asarray(table.rod_length)[table.index_of(ids)]
        shapes.append((np.asarray(theta) + offsets, length, np.asarray(steps) * math.pi / 6))
    reach = max(float(np.sum(s[1]) + 5e-3 * len(s[1])) for s in shapes) + 15e-3
    size = int(2 * reach / pixel_size)
    pose = ImagePose(reach, reach, 0.0)
    a, b = (render_silhouette(*shape, pose, pixel_size, (size, size), supersample=2) >= 0.5 for shape in shapes)
    return float(max(ndimage.distance_transform_edt(~b)[a].max(initial=0), ndimage.distance_transform_edt(~a)[b].max(initial=0)))


def _matches(chain, ids, steps, table, tolerance_deg: float) -> bool:
    """The reported chain cannot be told from the built one: same block count, rod lengths and rotation
    classes, and table angles within ``tolerance_deg`` block by block (the offsets drawn, plus 0.5 deg)."""
    if len(chain.blocks) != len(ids):
        return False
    found = table.index_of([b.design_id for b in chain.blocks])
    built = table.index_of(ids)
    lengths = np.allclose(np.asarray(table.rod_length)[found], np.asarray(table.rod_length)[built])
    angles = np.all(np.abs(np.asarray(table.theta0)[found] - np.asarray(table.theta0)[built]) <= math.radians(tolerance_deg))
    rotations = all(rotation_class(b.rotation_steps) == rotation_class(k) for b, k in zip(chain.blocks, steps))
    return bool(lengths and angles and rotations)


MISTAKE_KINDS = {"none": None, "wrong design": MistakeKind.WRONG_DESIGN, "flip (180 deg)": MistakeKind.WRONG_ROTATION,
                 "out of plane": MistakeKind.WRONG_ROTATION, "missing block": MistakeKind.MISSING_BLOCK,
                 "extra block": MistakeKind.EXTRA_BLOCK}
CONDITIONS = {  # name: (angle offsets +- [deg], the estimator's angle_sigma [deg])
    "uncalibrated": (MISTAKE_OFFSET_DEG, None),
    "calibrated": (0.5, 0.5),
}


MISTAKE_PIXELS = (0.25e-3, 0.4e-3)  # [m/px] the mistake study's pixel sizes
RESOLUTION_PIXELS = [0.1e-3, 0.25e-3, 0.4e-3, 0.5e-3, 1.0e-3]  # [m/px] the resolution study's


def mistake_study(table, rng, cases: int, pixel_sizes=MISTAKE_PIXELS, kinds=None, conditions=None) -> dict:
    records = []
    for pixel_size in pixel_sizes:
        records += _mistake_records(table, rng, cases, pixel_size, kinds=kinds, conditions=conditions)
    summary = {}
    for pixel_size in pixel_sizes:
        size = f"{1e3 * pixel_size:.2f} mm/px"
        chosen = [r for r in records if r["pixel_size_m"] == pixel_size]
        summary.update({f"{size}, {name}": row for name, row in _mistake_summary(chosen).items()})
    return {"summary": summary, "records": records, "pixel_sizes_m": list(pixel_sizes)}


def _mistake_records(table, rng, cases: int, pixel_size: float, options=None, kinds=None, conditions=None) -> list[dict]:
    records = []
    for condition, (offset_deg, sigma_deg) in CONDITIONS.items():
        if conditions is not None and condition not in conditions:
            continue
        chosen = dict(options or {}) | ({} if sigma_deg is None else {"angle_sigma": math.radians(sigma_deg)})
        for kind, expected in MISTAKE_KINDS.items():
            if kinds is not None and kind not in kinds:
                continue
            for case in range(cases):
                believed = [int(i) for i in rng.choice(table.ids, rng.integers(2, 9))]
                if kind == "missing block" and len(believed) < 3:
                    believed.append(int(rng.choice(table.ids)))
                steps = [0] * len(believed)
                ids, built_steps, k = (believed, steps, None) if expected is None else _mistake(kind, believed, steps, rng, table)
                offsets = np.radians(rng.uniform(-offset_deg, offset_deg, len(ids)))
                coverage, pose, _ = draw(table, ids, built_steps, offsets, pixel_size, rng)
                block_difference = None
                if kind in ("wrong design", "flip (180 deg)", "out of plane"):  # the two designs' shapes, one block
                    block_difference = _hausdorff_px(table, ([believed[k]], [0], offsets[k:k + 1]), ([ids[k]], [built_steps[k]], offsets[k:k + 1]), pixel_size)
                started = time.process_time()
                result = estimate_chain(to_binary(coverage), chain_of(believed, steps), pixel_size, pose, table=table,
                                        options=chosen or None)
                cpu = time.process_time() - started
                found = expected is None and result.as_built or any(m.kind is expected and m.position == k for m in result.mistakes)
                records.append({
                    "pixel_size_m": pixel_size, "condition": condition, "kind": kind, "believed": believed, "built": [int(i) for i in ids],
                    "built_steps": built_steps, "position": k, "block_difference_px": block_difference,
                    "found": bool(found), "equivalent": _matches(result.chain, ids, built_steps, table, offset_deg + 0.5),
                    "reported": [m.describe() for m in result.mistakes], "status": result.status.name, "cpu_s": cpu,
                })
                print(f"  {1e3 * pixel_size:.2f} mm/px, {condition}, {kind}: {case + 1}/{cases}   ", end="\r", flush=True)
            print()
    return records


def _mistake_summary(records: list[dict]) -> dict:
    summary = {}
    conditions = [c for c in CONDITIONS if any(r["condition"] == c for r in records)]
    for condition in conditions:  # the goal: a wrong design or rotation whose block shape differs by > 2 px
        rows = [r for r in records if r["condition"] == condition and r["block_difference_px"] is not None
                and r["block_difference_px"] > 2.0]
        summary[f"{condition}: design or rotation"] = {"counted": len(rows), "found": float(np.mean([r["found"] for r in rows])),
                                                       "equivalent": float(np.mean([r["equivalent"] for r in rows]))}
        for kind in MISTAKE_KINDS:
            rows = [r for r in records if r["condition"] == condition and r["kind"] == kind]
            if not rows:
                continue
            big = [r for r in rows if r["block_difference_px"] is None or r["block_difference_px"] > 2.0]
            summary[f"{condition}: {kind}"] = {
                "cases": len(rows), "counted": len(big),
                "found": float(np.mean([r["found"] for r in big])) if big else None,
                "equivalent": float(np.mean([r["equivalent"] for r in big])) if big else None,
                "found_all": float(np.mean([r["found"] for r in rows])),
                "median_cpu_s": float(np.median([r["cpu_s"] for r in rows])),
            }
    return summary


CANDIDATE_COUNTS = (1, 2, 3, 5, 8)
SWEEP_KINDS = ("wrong design", "flip (180 deg)", "out of plane", "missing block", "extra block")


def candidate_study(table, seed: int, cases: int, pixel_size: float = 0.4e-3) -> dict:
    """Recall and time against the number of candidates refined: the same images (one seeded stream per
    count) with one mistake each, uncalibrated."""
    rows = []
    for count in CANDIDATE_COUNTS:
        records = _mistake_records(table, np.random.default_rng([seed, 4]), cases, pixel_size,
                                   options={"refine_candidates": count}, kinds=SWEEP_KINDS, conditions=["uncalibrated"])
        separable = [r for r in records if r["block_difference_px"] is None or r["block_difference_px"] > 2.0]
        rows.append({"refine_candidates": count, "images": len(records), "counted": len(separable),
                     "found": float(np.mean([r["found"] for r in separable])),
                     "median_cpu_s": float(np.median([r["cpu_s"] for r in records])),
                     "p90_cpu_s": float(np.percentile([r["cpu_s"] for r in records], 90)),
                     "missed": [r for r in separable if not r["found"]]})
        print(f"  {count} candidates: found {rows[-1]['found']:.3f} of {len(separable)}, "
              f"median {1e3 * rows[-1]['median_cpu_s']:.0f} ms")
    return {"pixel_size_m": pixel_size, "cases_per_kind": cases, "rows": rows}


def time_study(table, rng, cases: int, repeats: int = 3) -> dict:
    """Time per as-built image against the block count: per image the best of ``repeats`` runs (the machine
    is shared; the best run is the least disturbed), then the median over the images."""
    rows = []
    for blocks in range(2, 9):
        cpu, wall = [], []
        for _ in range(cases):
            ids = rng.choice(table.ids, blocks)
            coverage, pose, _ = draw(table, ids, None, np.radians(rng.uniform(-OFFSET_DEG, OFFSET_DEG, blocks)), PIXEL, rng)
            image = to_binary(coverage)
            runs = []
            for _ in range(repeats):
                started, started_cpu = time.perf_counter(), time.process_time()
                estimate_chain(image, chain_of(ids), PIXEL, pose, table=table)
                runs.append((time.process_time() - started_cpu, time.perf_counter() - started))
            cpu.append(min(r[0] for r in runs))
            wall.append(min(r[1] for r in runs))
        rows.append({"blocks": blocks, "median_cpu_s": float(np.median(cpu)), "median_wall_s": float(np.median(wall)),
                     "p90_cpu_s": float(np.percentile(cpu, 90))})
        print(f"  time: {blocks} blocks, median {1e3 * rows[-1]['median_cpu_s']:.1f} ms CPU")
    return {"rows": rows, "repeats": repeats}


# ------------------------------------------------------------------------------------------- output
def plot(results: dict, path: Path) -> None:
    figure, axes = plt.subplots(2, 2, figsize=(12, 9))
    ax = axes[0, 0]
    rows = results["resolution"]["rows"]
    ax.boxplot([np.abs(r["errors_deg"]) for r in rows], positions=range(len(rows)), whis=(5, 95), showfliers=True)
    ax.set_xticks(range(len(rows)), [f"{1e3 * r['pixel_size_m']:.2f}" for r in rows])
    ax.axhline(0.5, color="tab:red", ls="--", lw=1, label="goal at 0.25 mm/px")
    ax.set(xlabel="pixel size [mm]", ylabel="|angle error| [deg]", yscale="log",
           title=f"as built, offsets +-{OFFSET_DEG:.0f} deg, 2-8 blocks")
    ax.legend(fontsize="small")
    ax = axes[0, 1]
    rows = results["faults"]["rows"]
    ax.barh(range(len(rows)), [r["p95_abs_error_deg"] for r in rows], color="tab:blue", label="95th percentile")
    ax.barh(range(len(rows)), [r["median_abs_error_deg"] for r in rows], color="tab:orange", label="median")
    ax.set_yticks(range(len(rows)), [f"{r['fault']} ({r['as_built']}/{r['cases']} as built)" for r in rows], fontsize="small")
    ax.axvline(0.5, color="tab:red", ls="--", lw=1)
    ax.set(xlabel="|angle error| [deg] at 0.25 mm/px", title="image faults")
    ax.invert_yaxis()
    ax.legend(fontsize="small")
    ax = axes[1, 0]
    records = [r for r in results["mistakes"]["records"] if r.get("pixel_size_m", PIXEL) == PIXEL]
    edges = [0, 1, 2, 4, 8, 16, math.inf]  # bins (lo, hi], so that the goal's "> 2 px" starts a bin
    labels = ["<=1", "1-2", "2-4", "4-8", "8-16", ">16"]
    for condition, style in zip(CONDITIONS, ("-", "--")):
        for group, kinds, colour in (("wrong design", ("wrong design",), "tab:blue"),
                                     ("wrong rotation", ("flip (180 deg)", "out of plane"), "tab:orange")):
            rows = [r for r in records if r["condition"] == condition and r["kind"] in kinds]
            difference = np.array([r["block_difference_px"] for r in rows])
            found = np.array([r["found"] for r in rows], dtype=float)
            which = np.digitize(difference, edges, right=True) - 1
            rate = [found[which == i].mean() if np.any(which == i) else np.nan for i in range(len(labels))]
            counts = [int(np.sum(which == i)) for i in range(len(labels))]
            ax.plot(range(len(labels)), rate, style, marker="o", color=colour,
                    label=f"{group}, {condition} (n per bin {counts})")
    ax.axvline(1.5, color="tab:red", ls=":", lw=1)
    ax.axhline(0.95, color="tab:red", ls=":", lw=1)
    ax.set_xticks(range(len(labels)), labels)
    ax.set(xlabel="believed and built block differ by [pixels] (Hausdorff, side view)", ylabel="found at the right block",
           ylim=(-0.05, 1.05), title="one mistake per chain, 0.25 mm/px")
    ax.legend(fontsize="x-small", loc="lower right")
    ax = axes[1, 1]
    rows = results["time"]["rows"]
    ax.plot([r["blocks"] for r in rows], [1e3 * r["median_cpu_s"] for r in rows], "o-", label="as built: median CPU")
    ax.plot([r["blocks"] for r in rows], [1e3 * r["median_wall_s"] for r in rows], "s--", label="as built: median wall")
    summary = [row for name, row in results["mistakes"]["summary"].items() if "median_cpu_s" in row and not name.endswith(": none")]
    ax.axhline(1e3 * np.median([row["median_cpu_s"] for row in summary]), color="tab:gray", ls=":",
               label="with a mistake: median CPU")
    ax.axhline(50, color="tab:red", ls="--", lw=1, label="goal (8 blocks)")
    ax.set(xlabel="blocks", ylabel="time per image [ms]", yscale="log", title="time per image (one core)")
    ax.legend(fontsize="small")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    if "candidates" in results:
        plot_candidates(results["candidates"], path.with_name("image_estimation_candidates.png"))


def plot_candidates(study: dict, path: Path) -> None:
    rows = study["rows"]
    figure, ax = plt.subplots(figsize=(6.5, 4.5))
    cpu = [1e3 * r["median_cpu_s"] for r in rows]
    ax.plot(cpu, [100 * r["found"] for r in rows], "o-")
    for r, x in zip(rows, cpu):
        ax.annotate(f"{r['refine_candidates']}", (x, 100 * r["found"]), textcoords="offset points", xytext=(5, -12))
    ax.axhline(98, color="tab:red", ls="--", lw=1, label="goal 98 %")
    ax.set(xlabel="median CPU time per image with a mistake [ms]", ylabel="separable mistakes found [%]",
           title=f"candidates refined (labels) at {1e3 * study['pixel_size_m']:.2f} mm/px, "
                 f"{rows[0]['counted']} mistakes")
    ax.legend(fontsize="small")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="few cases per point (a smoke run)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cases", type=int, help="cases per point instead of each study's default")
    parser.add_argument("--pixel-sizes", type=float, nargs="+", default=RESOLUTION_PIXELS,
                        help="pixel sizes [m] of the resolution study (with --only, the other sizes' rows are kept)")
    parser.add_argument("--kinds", nargs="+", choices=list(MISTAKE_KINDS), help="the mistake study's kinds (default: all)")
    parser.add_argument("--conditions", nargs="+", choices=list(CONDITIONS), help="the mistake study's conditions (default: all)")
    parser.add_argument("--replot", action="store_true", help="redraw the PNG from the JSON written before")
    parser.add_argument("--only", choices=["resolution", "faults", "mistakes", "time", "candidates"],
                        help="rerun one study into the JSON written before, and redraw the figure")
    args = parser.parse_args()
    if args.replot:
        plot(json.loads((FIGURES / "image_estimation.json").read_text()), FIGURES / "image_estimation.png")
        return
    table = load_table()
    scale = 0.2 if args.quick else 1.0
    count = lambda n: args.cases or max(2, int(n * scale))  # noqa: E731
    started = time.perf_counter()
    rng = lambda study: np.random.default_rng([args.seed, study])  # noqa: E731  (each study draws on its own)
    studies = {
        "resolution": ("angle accuracy against resolution",
                       lambda: resolution_study(table, rng(0), count(40), args.pixel_sizes)),
        "faults": ("image faults", lambda: fault_study(table, rng(1), count(30))),
        "mistakes": ("assembly mistakes", lambda: mistake_study(table, rng(2), count(100), kinds=args.kinds,
                                                                conditions=args.conditions)),
        "time": ("time per image", lambda: time_study(table, rng(3), count(20))),
        "candidates": ("recall and time against the candidates refined", lambda: candidate_study(table, args.seed, count(20))),
    }
    folder = QUICK_OUTPUT if args.quick else FIGURES
    path = folder / "image_estimation.json"
    if args.only:  # rerun one study into the results written before (read again when writing: see below)
        results = {"machine": {}}
        chosen = [args.only]
    else:
        results = {"seed": args.seed, "quick": args.quick, "offset_deg": OFFSET_DEG, "mistake_offset_deg": MISTAKE_OFFSET_DEG,
                   "machine": {"platform": platform.platform(), "python": platform.python_version()}}
        chosen = list(studies)
    for number, name in enumerate(chosen, start=1):
        title, run = studies[name]
        print(f"[{number}/{len(chosen)}] {title}")
        load = [round(v, 2) for v in os.getloadavg()]
        results[name] = run()
        results["machine"][f"{name}_load"] = {"before": load, "after": [round(v, 2) for v in os.getloadavg()]}
    results["total_s"] = time.perf_counter() - started
    folder.mkdir(parents=True, exist_ok=True)
    if args.only:  # merged into the file as it is now, so that several --only runs may share it
        results = _merged(json.loads(path.read_text()), results, args.only)
    path.write_text(json.dumps(results, indent=1))
    plot(results, folder / "image_estimation.png")
    report(results)
    print(f"wrote {path} and .png in {time.perf_counter() - started:.0f} s")


def _merged(written: dict, new: dict, study: str) -> dict:
    if study == "resolution":  # rows of the sizes not rerun are kept
        sizes = {row["pixel_size_m"] for row in new[study]["rows"]}
        kept = [row for row in written[study]["rows"] if row["pixel_size_m"] not in sizes]
        new[study]["rows"] = sorted(kept + new[study]["rows"], key=lambda row: row["pixel_size_m"])
    written[study] = new[study]
    written.setdefault("machine", {}).update(new["machine"])
    return written


def report(results: dict) -> None:
    for row in results["resolution"]["rows"]:
        print(f"{1e3 * row['pixel_size_m']:.2f} mm/px: median |error| {row['median_abs_error_deg']:.3f} deg, "
              f"95% {row['p95_abs_error_deg']:.3f}, max {row['max_abs_error_deg']:.3f}; false alarms {row['false_alarms']}/{row['cases']}")
    for row in results["faults"]["rows"]:
        print(f"{row['fault']}: median {row['median_abs_error_deg']:.3f} deg, 95% {row['p95_abs_error_deg']:.3f}, "
              f"as built {row['as_built']}/{row['cases']}")
    for label, row in results["mistakes"]["summary"].items():
        print(f"{label}: found {row['found']:.3f} / equivalent {row['equivalent']:.3f} of {row['counted']} "
              f"(block shapes differ > 2 px); found {row.get('found_all', math.nan):.2f} of all {row.get('cases', '-')}")
    for row in results.get("candidates", {}).get("rows", []):
        print(f"{row['refine_candidates']} candidates: found {row['found']:.3f} of {row['counted']}, "
              f"median {1e3 * row['median_cpu_s']:.0f} ms CPU")
    for row in results["time"]["rows"]:
        print(f"{row['blocks']} blocks: median {1e3 * row['median_cpu_s']:.1f} ms CPU, {1e3 * row['median_wall_s']:.1f} ms wall")


if __name__ == "__main__":
    main()
