"""Image estimation: angle accuracy, mistake recovery and time per image on synthetic side views.

Chains of 2-8 random table designs (every block with a random angle offset within the estimator's
manufacturing tolerance) are drawn with a random growth direction and mirror state by two renderers that
share no code with the estimator's forward model nor with each other: the reference renderer
(estimation.render: filled hulls of projected cross-section discs) and the capsule renderer
(tests/estimation/capsule_render.py: the centreline as a thick polyline with flat end faces). Each image is
estimated with estimation.estimate_chain given the believed chain. Studies:

  resolution  as-built chains at 0.1-1 mm/px: angle errors and false alarms
  faults      at 0.25 and 0.4 mm/px: clean, pixel noise, blur, grey noise, an occluded tip
  mistakes    at 0.25 and 0.4 mm/px: one wrong design, wrong rotation (flip or out of plane), missing or extra
              block; found = the right kind, and the chain reported is the one built (the built design among
              the designs named, the right rotation class, a missing or extra block at its place or at an
              equivalent one). Each wrong design or rotation carries how far the built block's shape lies
              from the believed design's (Hausdorff distance of the two blocks' side views, in pixels): with
              the same offset, and beyond what any offset within the tolerance explains (the goal counts
              the mistakes that differ by more than 2 px)
  time        CPU (time.process_time) and wall time per as-built image against the block count (one core)
  candidates  at 0.4 mm/px: separable mistakes found and time per image against the candidates refined

Writes docs/figures/image_estimation.json, image_estimation.png and image_estimation_candidates.png (--quick: a
smoke run into out/benchmarks/; --only STUDY [STUDY ...] reruns those studies into the JSON written before;
--replot redraws the figures). Each study draws from its own seeded stream.
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

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # this checkout's packages, not an installed copy
sys.path.insert(0, str(ROOT / "tests" / "estimation"))  # the capsule renderer
from capsule_render import capsule_chain, capsule_silhouette  # noqa: E402

from estimation.estimate import EstimateOptions, estimate_chain  # noqa: E402
from estimation.hypotheses import MistakeKind, rotation_class  # noqa: E402
from estimation.render import blurred, render_chain, to_binary, with_grey_noise, with_pixel_noise  # noqa: E402
from estimation.view import ImagePose  # noqa: E402
from planner.assembly import Chain, PlacedBlock  # noqa: E402
from planner.table import load_table  # noqa: E402

FIGURES = ROOT / "docs" / "figures"
QUICK_OUTPUT = ROOT / "out" / "benchmarks"
TOLERANCE_DEG = math.degrees(EstimateOptions().angle_tolerance)  # as-built offsets: uniform within +-this
RENDERERS = {"reference": render_chain, "capsule": capsule_chain}
PIXELS = (0.25e-3, 0.4e-3)  # [m/px] the sizes the goals are stated at
RESOLUTION_PIXELS = [0.1e-3, 0.25e-3, 0.4e-3, 0.5e-3, 1.0e-3]
SEPARABLE_PX = 2.0  # the goal counts mistakes whose block shapes differ by more than this


def chain_of(ids, steps=None) -> Chain:
    steps = steps if steps is not None else [0] * len(ids)
    return Chain("bench", "main", tuple(PlacedBlock(int(i), int(k)) for i, k in zip(ids, steps)))


def draw(renderer: str, table, ids, steps, offsets, pixel_size, view):
    """Coverage image, base pose and angles drawn; ``view`` = (growth angle, mirrored)."""
    return RENDERERS[renderer](ids, steps, table, pixel_size, offsets=offsets, angle=view[0], mirrored=view[1])


def random_view(rng) -> tuple[float, bool]:
    return float(rng.uniform(0, 2 * np.pi)), bool(rng.integers(2))


def timed(image, chain, pose, table, pixel_size, threshold=None, occlusion=None, options=None):
    started = time.process_time()
    result = estimate_chain(image, chain, pixel_size, pose, table=table, threshold=threshold, occlusion=occlusion,
                            options=options)
    return result, time.process_time() - started


def angle_errors(result, theta, visible=None) -> list[float]:
    if len(result.blocks) != len(theta):
        return []
    errors = np.degrees(result.theta - theta)
    return [float(e) for e in (errors if visible is None else errors[:visible])]


def _error_summary(errors) -> dict:
    absolute = np.abs(errors) if len(errors) else np.array([np.nan])
    return {"angles": len(errors), "median_abs_error_deg": float(np.median(absolute)),
            "p95_abs_error_deg": float(np.percentile(absolute, 95)), "max_abs_error_deg": float(np.max(absolute)),
            "within_0_5_deg": float(np.mean(absolute <= 0.5))}


def progress(text: str) -> None:
    print(f"  {text}      ", end="\r", flush=True)


def offsets_within_tolerance(rng, count: int, limit_deg: float = TOLERANCE_DEG) -> np.ndarray:
    return np.radians(rng.uniform(-limit_deg, limit_deg, count))


# ------------------------------------------------------------------------------------------ studies
def resolution_study(table, rng, cases: int, sizes, renderers) -> dict:
    rows = []
    for size in sizes:
        for renderer in renderers:
            errors, alarms, times, z = [], 0, [], []
            for case in range(cases):
                ids = rng.choice(table.ids, rng.integers(2, 9))
                coverage, pose, theta = draw(renderer, table, ids, None, offsets_within_tolerance(rng, len(ids)), size,
                                             random_view(rng))
                result, cpu = timed(to_binary(coverage), chain_of(ids), pose, table, size)
                errors += angle_errors(result, theta)
                if len(result.blocks) == len(theta):
                    z += list(np.abs(result.theta - theta) / result.theta_std)
                alarms += not result.as_built
                times.append(cpu)
                progress(f"resolution {1e3 * size:.2f} mm/px, {renderer}: {case + 1}/{cases}")
            print()
            rows.append(_error_summary(errors) | {
                "pixel_size_m": size, "renderer": renderer, "cases": cases, "false_alarms": alarms,
                "median_cpu_s": float(np.median(times)),
                "within_2_sigma": float(np.mean(np.array(z) <= 2.0)) if z else None, "errors_deg": errors,
            })
    return {"rows": rows, "offset_deg": TOLERANCE_DEG}


FAULTS = {
    "clean": lambda c, r: (to_binary(c), None),
    "pixel noise 1%": lambda c, r: (with_pixel_noise(to_binary(c), 0.01, r), None),
    "pixel noise 5%": lambda c, r: (with_pixel_noise(to_binary(c), 0.05, r), None),
    "blur 1 px": lambda c, r: (to_binary(blurred(c, 1.0)), None),
    "blur 2 px + grey": lambda c, r: (np.round(255 * blurred(c, 2.0)).astype(np.uint8), 127.5),
    "grey noise 10%": lambda c, r: (with_grey_noise(c, 0.1, r), 127.5),
}
OCCLUDERS = {"occluded tip, round occluder": "disc", "occluded tip, straight edge": "edge",
             "occluded tip, straight edge given": "edge given"}


def fault_study(table, rng, cases: int, sizes, renderers) -> dict:
    rows = []
    for size in sizes:
        for renderer in renderers:
            for name, fault in list(FAULTS.items()) + list(OCCLUDERS.items()):
                errors, as_built, times, refused = [], 0, [], 0
                for case in range(cases):
                    ids = rng.choice(table.ids, rng.integers(2, 9))
                    coverage, pose, theta = draw(renderer, table, ids, None, offsets_within_tolerance(rng, len(ids)), size,
                                                 random_view(rng))
                    visible, occlusion, threshold = None, None, None
                    if isinstance(fault, str):
                        image, hidden = _occlude_tip(coverage, pose, ids, theta, table, rng, fault, size)
                        occlusion = hidden if fault == "edge given" else None
                        visible = len(ids) - 1  # angle errors of the blocks before the last
                    else:
                        image, threshold = fault(coverage, rng)
                    try:
                        result, cpu = timed(image, chain_of(ids), pose, table, size, threshold, occlusion)
                    except ValueError as error:  # e.g. noise split the silhouette: counted as refused
                        print(f"\n  {name}: {error}")
                        refused += 1
                        continue
                    errors += angle_errors(result, theta, visible)
                    as_built += result.as_built
                    times.append(cpu)
                    progress(f"faults {1e3 * size:.2f} mm/px, {renderer}, {name}: {case + 1}/{cases}")
                print()
                rows.append(_error_summary(errors) | {"fault": name, "pixel_size_m": size, "renderer": renderer,
                                                      "cases": cases, "as_built": as_built, "refused": refused,
                                                      "median_cpu_s": float(np.median(times)) if times else None})
    return {"rows": rows}


def _occlude_tip(coverage, pose, ids, theta, table, rng, shape: str, pixel_size: float):
    """The image with part of the last block hidden, and the hidden pixels. ``disc``: a disc of one block
    radius near the tip; ``edge``/``edge given``: an occluder with a straight edge across the last block,
    3-10 mm from the tip, at a random angle within +-45 deg of square to the block's axis, covering the
    tip out to two block radii (so it never reaches back to the rest of a curled chain)."""
    from estimation.render import cross_section_frames

    rows = table.index_of(ids)
    end = cross_section_frames(theta, np.asarray(table.rod_length)[rows], np.zeros(len(ids)))[-1]
    tip = pose.to_image(end[[0, 2], 3]) / pixel_size
    columns, rows_ = np.meshgrid(np.arange(coverage.shape[1]) + 0.5, np.arange(coverage.shape[0]) + 0.5)
    if shape == "disc":
        centre = tip + rng.normal(0, 2.5e-3 / pixel_size, 2)
        hidden = (columns - centre[0]) ** 2 + (rows_ - centre[1]) ** 2 <= (12.5e-3 / pixel_size) ** 2
    else:
        axis = pose.directions_to_image(end[[0, 2], 2])  # the tip's axis in the image
        cut = tip - axis * rng.uniform(3e-3, 10e-3) / pixel_size
        tilt = rng.uniform(-np.pi / 4, np.pi / 4)
        normal = np.array([[np.cos(tilt), -np.sin(tilt)], [np.sin(tilt), np.cos(tilt)]]) @ axis
        near_tip = (columns - tip[0]) ** 2 + (rows_ - tip[1]) ** 2 <= (25e-3 / pixel_size) ** 2
        hidden = near_tip & ((columns - cut[0]) * normal[0] + (rows_ - cut[1]) * normal[1] > 0)
    return np.where(hidden, 0, to_binary(coverage)).astype(np.uint8), hidden


MISTAKE_KINDS = {"none": None, "wrong design": MistakeKind.WRONG_DESIGN, "flip (180 deg)": MistakeKind.WRONG_ROTATION,
                 "out of plane": MistakeKind.WRONG_ROTATION, "missing block": MistakeKind.MISSING_BLOCK,
                 "extra block": MistakeKind.EXTRA_BLOCK}
SHAPE_KINDS = ("wrong design", "flip (180 deg)", "out of plane")  # the kinds whose separability is measured
CONDITIONS = {  # name: (angle offsets +- [deg], the estimator's angle_tolerance [deg])
    "uncalibrated": (TOLERANCE_DEG, None),
    "calibrated": (0.5, 0.5),
}


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


def block_difference_px(table, believed_id: int, built_id: int, built_step: int, built_offset: float, pixel_size: float,
                        tolerance: float) -> tuple[float, float]:
    """How far a built block's side view lies from the believed design's, in pixels (Hausdorff distance, one
    block on one base, rendered by the capsule renderer): with the same offset, and the least over the
    believed design's offsets within +-``tolerance`` (what no manufacturing offset explains)."""
    theta = np.asarray(table.angle_at([believed_id, built_id], 0.0)[0], dtype=float)
    length = np.asarray(table.rod_length, dtype=float)[table.index_of([believed_id, built_id])]
    reach = float(length.max()) + 20e-3
    size = int(math.ceil(2 * reach / pixel_size))
    frame = (ImagePose(reach, reach, 0.0), (size, size))

    def mask(angle, rod, step):
        return capsule_silhouette([angle], [rod], [step], pixel_size, frame=frame, samples=1)[0] >= 0.5

    built = mask(theta[1] + built_offset, length[1], built_step)

    def distance(offset: float) -> float:
        return _hausdorff(mask(theta[0] + offset, length[0], 0), built)

    same = distance(built_offset)
    nearest = float(np.clip(theta[1] + built_offset - theta[0], -tolerance, tolerance))
    trials = np.unique(np.concatenate([np.linspace(-tolerance, tolerance, 9), [nearest, built_offset]]))
    return same, min(same, *(distance(o) for o in trials))


def named_right(result, built, built_steps, drawn, expected, position, table, tolerance: float) -> bool:
    """The mistake is found and named: a mistake of the expected kind, and the chain reported is the chain
    built. Block by block: the same rod length and rotation class, and the block as drawn is an as-built
    instance of a design reported for it (its angle within the tolerance of it, plus 0.5 deg of measurement;
    the designs named for a block a mistake changed, else its one design); a wrong design or an extra block
    reported at the place it was made names the built design among its designs. (A missing or extra block
    next to blocks alike is reported at any of their places: the chains are the same.)"""
    if expected is None:
        return result.as_built
    if not any(m.kind is expected for m in result.mistakes) or len(result.blocks) != len(built):
        return False
    designs = {m.position: m.likely_design_ids for m in result.mistakes if m.kind is MistakeKind.WRONG_DESIGN}
    extra = {m.position: m.likely_design_ids for m in result.mistakes if m.kind is MistakeKind.EXTRA_BLOCK}
    length = dict(zip(table.ids, np.asarray(table.rod_length, dtype=float)))
    angle = dict(zip(table.ids, np.asarray(table.angle_at(table.ids, 0.0)[0], dtype=float)))
    believed_count = 1 + max([b.believed_position for b in result.blocks if b.believed_position is not None]
                             + [m.position for m in result.mistakes if m.kind is MistakeKind.MISSING_BLOCK])
    for block, design, step, theta in zip(result.blocks, built, built_steps, drawn):
        if block.believed_position is None:  # an extra block: named by the believed block it sits before
            after = [b.believed_position for b in result.blocks[block.position:] if b.believed_position is not None]
            reported = extra.get(after[0] if after else believed_count, ())
            if not reported:
                return False
        else:
            reported = designs.get(block.believed_position, (block.design_id,))
        if rotation_class(block.rotation_steps) != rotation_class(step) or not math.isclose(length[reported[0]], length[design]):
            return False
        if not any(abs(theta - angle[d]) <= tolerance + math.radians(0.5) for d in reported):
            return False
    if expected is MistakeKind.WRONG_DESIGN and position in designs and built[position] not in designs[position]:
        return False
    if expected is MistakeKind.EXTRA_BLOCK and position in extra and built[position] not in extra[position]:
        return False
    return True


def equivalent_report(result, built, built_steps, drawn, expected, table, tolerance: float, pixel_size: float) -> bool:
    """A mistake of the expected kind is reported and the chain reported explains the image as well as the
    one built: drawn (capsule renderer, same base) at the measured angles, each held within the tolerance of
    its block's design, its side view lies within SEPARABLE_PX of the built chain's (Hausdorff). Such a
    mistake cannot be told from the one reported (e.g. an extra block among several nearly straight ones)."""
    if expected is None or not any(m.kind is expected for m in result.mistakes):
        return False
    angle = np.asarray(table.angle_at([b.design_id for b in result.blocks], 0.0)[0], dtype=float)
    reported = np.clip(result.theta, angle - tolerance, angle + tolerance)
    length = np.asarray(table.rod_length, dtype=float)
    chains = ((reported, length[table.index_of([b.design_id for b in result.blocks])], [b.rotation_steps for b in result.blocks]),
              (np.asarray(drawn), length[table.index_of(built)], built_steps))
    reach = max(float(np.sum(c[1])) + 5e-3 * len(c[1]) for c in chains) + 20e-3
    size = int(math.ceil(2 * reach / pixel_size))
    frame = (ImagePose(reach, reach, 0.0), (size, size))
    first, second = (capsule_silhouette(*c, pixel_size, frame=frame, samples=1)[0] >= 0.5 for c in chains)
    return _hausdorff(first, second) <= SEPARABLE_PX


def _hausdorff(first: np.ndarray, second: np.ndarray) -> float:
    """Hausdorff distance [pixels] between two masks."""
    return float(max(ndimage.distance_transform_edt(~second)[first].max(initial=0),
                     ndimage.distance_transform_edt(~first)[second].max(initial=0)))


def found_at(result, expected, position) -> bool:
    """The earlier, weaker criterion: a mistake of the right kind at the right believed block."""
    if expected is None:
        return result.as_built
    return any(m.kind is expected and m.position == position for m in result.mistakes)


def mistake_study(table, rng, cases: int, pixel_sizes=PIXELS, kinds=None, conditions=None, renderers=tuple(RENDERERS),
                  options=None) -> dict:
    records = []
    for pixel_size in pixel_sizes:
        records += _mistake_records(table, rng, cases, pixel_size, kinds=kinds, conditions=conditions, renderers=renderers,
                                    options=options)
    return {"summary": _mistake_summary(records), "records": records, "pixel_sizes_m": list(pixel_sizes),
            "renderers": list(renderers), "separable_px": SEPARABLE_PX}


def _mistake_records(table, rng, cases: int, pixel_size: float, options=None, kinds=None, conditions=None,
                     renderers=tuple(RENDERERS)) -> list[dict]:
    records = []
    for condition, (offset_deg, tolerance_deg) in CONDITIONS.items():
        if conditions is not None and condition not in conditions:
            continue
        chosen = dict(options or {}) | ({} if tolerance_deg is None else {"angle_tolerance": math.radians(tolerance_deg)})
        tolerance = chosen.get("angle_tolerance", EstimateOptions().angle_tolerance)
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
                view = random_view(rng)
                same = beyond = None
                if kind in SHAPE_KINDS:
                    same, beyond = block_difference_px(table, believed[k], ids[k], built_steps[k], offsets[k], pixel_size, tolerance)
                for renderer in renderers:
                    coverage, pose, drawn = draw(renderer, table, ids, built_steps, offsets, pixel_size, view)
                    try:
                        result, cpu = timed(to_binary(coverage), chain_of(believed, steps), pose, table, pixel_size,
                                            options=chosen or None)
                    except ValueError as error:  # e.g. a chain curled over its own base: counted as missed
                        records.append({"pixel_size_m": pixel_size, "renderer": renderer, "condition": condition, "kind": kind,
                                        "believed": believed, "built": [int(i) for i in ids], "built_steps": built_steps,
                                        "position": k, "difference_same_offset_px": same, "difference_beyond_tolerance_px": beyond,
                                        "found": False, "equivalent": False, "found_kind_and_place": False, "named_designs": [],
                                        "reported": [], "status": f"refused: {error}", "cpu_s": None})
                        continue
                    records.append({
                        "pixel_size_m": pixel_size, "renderer": renderer, "condition": condition, "kind": kind,
                        "believed": believed, "built": [int(i) for i in ids], "built_steps": built_steps, "position": k,
                        "offsets_deg": [round(float(o), 3) for o in np.degrees(offsets)],
                        "difference_same_offset_px": same, "difference_beyond_tolerance_px": beyond,
                        "found": (found := named_right(result, ids, built_steps, drawn, expected, k, table, tolerance)),
                        "equivalent": found or equivalent_report(result, ids, built_steps, drawn, expected, table, tolerance,
                                                                 pixel_size),
                        "found_kind_and_place": found_at(result, expected, k),
                        "named_designs": [len(m.likely_design_ids) for m in result.mistakes if m.likely_design_ids],
                        "reported": [m.describe() for m in result.mistakes], "status": result.status.name, "cpu_s": cpu,
                    })
                progress(f"{1e3 * pixel_size:.2f} mm/px, {condition}, {kind}: {case + 1}/{cases}")
            print()
    return records


def separable(record: dict) -> bool:
    """Counted by the goal: missing and extra blocks always; a wrong design or rotation whose block shape
    differs by more than SEPARABLE_PX beyond what offsets within the tolerance explain."""
    if record["kind"] == "none":
        return False
    beyond = record["difference_beyond_tolerance_px"]
    return beyond is None or beyond > SEPARABLE_PX


def _rate(rows, key="found") -> float | None:
    return float(np.mean([r[key] for r in rows])) if rows else None


def _mistake_summary(records: list[dict]) -> dict:
    summary = {}
    groups = sorted({(r["pixel_size_m"], r["renderer"], r["condition"]) for r in records})
    for pixel_size, renderer, condition in groups:
        chosen = [r for r in records if (r["pixel_size_m"], r["renderer"], r["condition"]) == (pixel_size, renderer, condition)]
        label = f"{1e3 * pixel_size:.2f} mm/px, {renderer}, {condition}"
        counted = [r for r in chosen if separable(r)]
        same = [r for r in chosen if r["kind"] in SHAPE_KINDS and r["difference_same_offset_px"] > SEPARABLE_PX]
        summary[label] = {"kind": "all mistakes, separable", "counted": len(counted), "found": _rate(counted),
                          "equivalent": _rate(counted, "equivalent"),
                          "found_kind_and_place": _rate(counted, "found_kind_and_place"),
                          "shape_same_offset_counted": len(same), "shape_same_offset_found": _rate(same)}
        for kind in MISTAKE_KINDS:
            rows = [r for r in chosen if r["kind"] == kind]
            if not rows:
                continue
            big = rows if kind == "none" else [r for r in rows if separable(r)]
            names = [n for r in big for n in r["named_designs"]]
            summary[f"{label}: {kind}"] = {
                "kind": kind, "cases": len(rows), "counted": len(big), "found": _rate(big),
                "equivalent": _rate(big, "equivalent"), "found_kind_and_place": _rate(big, "found_kind_and_place"), "found_all": _rate(rows),
                "median_designs_named": float(np.median(names)) if names else None,
                "median_cpu_s": _median_cpu(rows),
            }
    return summary


def _median_cpu(records) -> float:
    """Median CPU time [s] of the images estimated (a refused image has none)."""
    return float(np.median([r["cpu_s"] for r in records if r["cpu_s"] is not None]))


CANDIDATE_COUNTS = (1, 2, 3, 5, 8)
SWEEP_KINDS = ("wrong design", "flip (180 deg)", "out of plane", "missing block", "extra block")


def candidate_study(table, seed: int, cases: int, pixel_size: float = 0.4e-3, renderer: str = "capsule") -> dict:
    """Recall and time against the number of candidates refined: the same images (one seeded stream per
    count) with one mistake each, uncalibrated, drawn by the capsule renderer."""
    rows = []
    for count in CANDIDATE_COUNTS:
        print(f"  {count} candidates refined:")
        records = _mistake_records(table, np.random.default_rng([seed, 4]), cases, pixel_size,
                                   options={"refine_candidates": count}, kinds=SWEEP_KINDS, conditions=["uncalibrated"],
                                   renderers=(renderer,))
        counted = [r for r in records if separable(r)]
        rows.append({"refine_candidates": count, "images": len(records), "counted": len(counted),
                     "found": _rate(counted), "equivalent": _rate(counted, "equivalent"),
                     "found_kind_and_place": _rate(counted, "found_kind_and_place"),
                     "median_cpu_s": _median_cpu(records),
                     "p90_cpu_s": float(np.percentile([r["cpu_s"] for r in records if r["cpu_s"] is not None], 90)),
                     "missed": [r for r in counted if not r["found"]]})
        print(f"  {count} candidates: found {rows[-1]['found']:.3f} of {len(counted)}, "
              f"median {1e3 * rows[-1]['median_cpu_s']:.0f} ms CPU")
    return {"pixel_size_m": pixel_size, "renderer": renderer, "cases_per_kind": cases, "rows": rows}


def time_study(table, rng, cases: int, repeats: int = 3, pixel_size: float = 0.25e-3) -> dict:
    """Time per as-built image against the block count, one estimate after the other in this process: CPU
    (time.process_time: every thread of the process) and wall time of each image's first run, and the best of
    ``repeats`` runs (the machine is shared; the best run is the least disturbed); medians and 90th
    percentiles over the images. Also the first estimate of the image drawn by the capsule renderer right
    before it: that renderer's large array operations wake numpy's BLAS worker threads, which then spin for
    a while and count as the process's CPU time (OPENBLAS_NUM_THREADS=1 has none); the estimating thread's
    own CPU time (time.thread_time) and the wall time show what the estimate itself took."""
    rows = []
    for blocks in range(2, 9):
        first_cpu, first_wall, best_cpu, best_wall, after_capsule = [], [], [], [], []
        for case in range(cases):
            ids = rng.choice(table.ids, blocks)
            offsets, view = offsets_within_tolerance(rng, blocks), random_view(rng)
            coverage, pose, _ = draw("reference", table, ids, None, offsets, pixel_size, view)
            image = to_binary(coverage)
            runs = []
            for _ in range(repeats):
                started, started_cpu = time.perf_counter(), time.process_time()
                estimate_chain(image, chain_of(ids), pixel_size, pose, table=table)
                runs.append((time.process_time() - started_cpu, time.perf_counter() - started))
            first_cpu.append(runs[0][0])
            first_wall.append(runs[0][1])
            best_cpu.append(min(r[0] for r in runs))
            best_wall.append(min(r[1] for r in runs))
            coverage, pose, _ = draw("capsule", table, ids, None, offsets, pixel_size, view)
            started, started_cpu, started_thread = time.perf_counter(), time.process_time(), time.thread_time()
            estimate_chain(to_binary(coverage), chain_of(ids), pixel_size, pose, table=table)
            after_capsule.append((time.process_time() - started_cpu, time.thread_time() - started_thread,
                                  time.perf_counter() - started))
            progress(f"time: {blocks} blocks, {case + 1}/{cases}")
        rows.append({"blocks": blocks, "images": cases,
                     "median_cpu_s": float(np.median(first_cpu)), "p90_cpu_s": float(np.percentile(first_cpu, 90)),
                     "median_wall_s": float(np.median(first_wall)), "p90_wall_s": float(np.percentile(first_wall, 90)),
                     "median_best_cpu_s": float(np.median(best_cpu)), "median_best_wall_s": float(np.median(best_wall)),
                     "median_cpu_after_capsule_render_s": float(np.median([t[0] for t in after_capsule])),
                     "median_thread_cpu_after_capsule_render_s": float(np.median([t[1] for t in after_capsule])),
                     "median_wall_after_capsule_render_s": float(np.median([t[2] for t in after_capsule]))})
        print(f"  time: {blocks} blocks, median {1e3 * rows[-1]['median_cpu_s']:.1f} ms CPU, "
              f"{1e3 * rows[-1]['median_wall_s']:.1f} ms wall (best of {repeats}: {1e3 * rows[-1]['median_best_cpu_s']:.1f} ms CPU; "
              f"right after a capsule render: {1e3 * rows[-1]['median_cpu_after_capsule_render_s']:.1f} ms CPU, "
              f"{1e3 * rows[-1]['median_thread_cpu_after_capsule_render_s']:.1f} ms of the thread, "
              f"{1e3 * rows[-1]['median_wall_after_capsule_render_s']:.1f} ms wall)")
    return {"rows": rows, "repeats": repeats, "pixel_size_m": pixel_size,
            "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "unset")}


# ------------------------------------------------------------------------------------------- output
def plot(results: dict, path: Path) -> None:
    figure, axes = plt.subplots(2, 2, figsize=(13, 9.5))
    ax = axes[0, 0]
    if "resolution" in results:
        rows = results["resolution"]["rows"]
        positions = np.arange(len(rows))
        ax.boxplot([np.abs(r["errors_deg"]) if r["errors_deg"] else [np.nan] for r in rows], positions=positions,
                   whis=(5, 95), showfliers=True)
        ax.set_xticks(positions, [f"{1e3 * r['pixel_size_m']:.2f}\n{r['renderer'][:3]}" for r in rows], fontsize="small")
        ax.axhline(0.5, color="tab:red", ls="--", lw=1, label="0.5 deg")
        ax.set(xlabel="pixel size [mm], renderer", ylabel="|angle error| [deg]", yscale="log",
               title=f"as built, offsets +-{results['resolution']['offset_deg']:.1f} deg, 2-8 blocks")
        ax.legend(fontsize="small")
    ax = axes[0, 1]
    if "faults" in results:
        rows = results["faults"]["rows"]
        y = np.arange(len(rows))
        ax.barh(y, [r["p95_abs_error_deg"] for r in rows], color="tab:blue", label="95th percentile")
        ax.barh(y, [r["median_abs_error_deg"] for r in rows], color="tab:orange", label="median")
        ax.set_yticks(y, [f"{1e3 * r['pixel_size_m']:.2f} {r['renderer'][:3]} {r['fault']} ({r['as_built']}/{r['cases']})"
                          for r in rows], fontsize=5)
        ax.axvline(0.5, color="tab:red", ls="--", lw=1)
        ax.set(xlabel="|angle error| [deg] (labels: as built / images)", title="image faults", xscale="log")
        ax.invert_yaxis()
        ax.legend(fontsize="small")
    ax = axes[1, 0]
    if "mistakes" in results:
        _plot_mistakes(ax, results["mistakes"]["records"])
    ax = axes[1, 1]
    if "time" in results:
        rows = results["time"]["rows"]
        blocks = [r["blocks"] for r in rows]
        ax.plot(blocks, [1e3 * r["median_cpu_s"] for r in rows], "o-", label="median CPU")
        ax.plot(blocks, [1e3 * r["p90_cpu_s"] for r in rows], "o:", label="90th percentile CPU")
        ax.plot(blocks, [1e3 * r["median_wall_s"] for r in rows], "s--", label="median wall")
        ax.plot(blocks, [1e3 * r["median_cpu_after_capsule_render_s"] for r in rows], "^:",
                label="right after a capsule render: median CPU, BLAS threads spinning")
        ax.plot(blocks, [1e3 * r["median_wall_after_capsule_render_s"] for r in rows], "v:",
                label="right after a capsule render: median wall")
        ax.axhline(50, color="tab:red", ls="--", lw=1, label="goal (8 blocks)")
        load = results.get("machine", {}).get("time_load", {}).get("before", ["?"])[0]
        ax.set(xlabel="blocks", ylabel="time per as-built image [ms]", ylim=(0, None),
               title=f"time per image, {1e3 * results['time']['pixel_size_m']:.2f} mm/px (one core, load {load})")
        ax.legend(fontsize="x-small", loc="upper left")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    if "candidates" in results:
        plot_candidates(results["candidates"], path.with_name("image_estimation_candidates.png"))


def _plot_mistakes(ax, records) -> None:
    edges = [0, 1, 2, 4, 8, 16, math.inf]  # bins (lo, hi], so that the goal's "> 2 px" starts a bin
    labels = ["<=1", "1-2", "2-4", "4-8", "8-16", ">16"]
    styles = {0.25e-3: "-", 0.4e-3: "--"}
    for pixel_size, style in styles.items():
        for group, kinds, colour in (("wrong design", ("wrong design",), "tab:blue"),
                                     ("wrong rotation", ("flip (180 deg)", "out of plane"), "tab:orange")):
            rows = [r for r in records if r["condition"] == "uncalibrated" and r["kind"] in kinds
                    and math.isclose(r["pixel_size_m"], pixel_size)]
            if not rows:
                continue
            difference = np.array([r["difference_beyond_tolerance_px"] for r in rows])
            found = np.array([r["found"] for r in rows], dtype=float)
            which = np.digitize(difference, edges, right=True) - 1
            rate = [found[which == i].mean() if np.any(which == i) else np.nan for i in range(len(labels))]
            counts = [int(np.sum(which == i)) for i in range(len(labels))]
            ax.plot(range(len(labels)), rate, style, marker="o", color=colour,
                    label=f"{group}, {1e3 * pixel_size:.2f} mm/px (n per bin {counts})")
    ax.axvline(1.5, color="tab:red", ls=":", lw=1)
    ax.axhline(0.98, color="tab:red", ls=":", lw=1)
    ax.set_xticks(range(len(labels)), labels)
    ax.set(xlabel="built block differs from the believed design beyond the tolerance by [px] (Hausdorff, side view)",
           ylabel="found and named", ylim=(-0.05, 1.05), title="one mistake per chain, both renderers, uncalibrated")
    ax.legend(fontsize="x-small", loc="lower right")


def plot_candidates(study: dict, path: Path) -> None:
    rows = study["rows"]
    figure, ax = plt.subplots(figsize=(6.5, 4.5))
    cpu = [1e3 * r["median_cpu_s"] for r in rows]
    ax.plot(cpu, [100 * r["found"] for r in rows], "o-", label="found and named")
    ax.plot(cpu, [100 * r["found_kind_and_place"] for r in rows], "s:", label="right kind and place")
    for r, x in zip(rows, cpu):
        ax.annotate(f"{r['refine_candidates']}", (x, 100 * r["found"]), textcoords="offset points", xytext=(5, -12))
    ax.axhline(98, color="tab:red", ls="--", lw=1, label="goal 98 %")
    ax.set(xlabel="median CPU time per image with a mistake [ms]", ylabel="separable mistakes [%]",
           title=f"candidates refined (labels) at {1e3 * study['pixel_size_m']:.2f} mm/px,\n"
                 f"{rows[0]['counted']} separable mistakes ({study['renderer']} renderer)")
    ax.legend(fontsize="small")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def report(results: dict) -> None:
    for row in results.get("resolution", {}).get("rows", []):
        print(f"{1e3 * row['pixel_size_m']:.2f} mm/px {row['renderer']}: median |error| {row['median_abs_error_deg']:.3f} deg, "
              f"95% {row['p95_abs_error_deg']:.3f}, max {row['max_abs_error_deg']:.3f}, within 0.5 deg "
              f"{100 * row['within_0_5_deg']:.1f} % of {row['angles']}; false alarms {row['false_alarms']}/{row['cases']}")
    for row in results.get("faults", {}).get("rows", []):
        print(f"{1e3 * row['pixel_size_m']:.2f} mm/px {row['renderer']} {row['fault']}: median {row['median_abs_error_deg']:.3f} deg, "
              f"95% {row['p95_abs_error_deg']:.3f}, within 0.5 deg {100 * row['within_0_5_deg']:.1f} %, "
              f"as built {row['as_built']}/{row['cases']}")
    for label, row in results.get("mistakes", {}).get("summary", {}).items():
        if row["found"] is not None:
            print(f"{label}: found and named {100 * row['found']:.1f} % of {row['counted']}, "
                  f"or an equivalent chain {100 * row['equivalent']:.1f} %")
    for row in results.get("candidates", {}).get("rows", []):
        print(f"{row['refine_candidates']} candidates: found {row['found']:.3f} of {row['counted']}, "
              f"median {1e3 * row['median_cpu_s']:.0f} ms CPU")
    for row in results.get("time", {}).get("rows", []):
        print(f"{row['blocks']} blocks: median {1e3 * row['median_cpu_s']:.1f} ms CPU, {1e3 * row['median_wall_s']:.1f} ms wall; "
              f"best of {results['time']['repeats']}: {1e3 * row['median_best_cpu_s']:.1f} ms CPU; "
              f"right after a capsule render {1e3 * row['median_cpu_after_capsule_render_s']:.1f} ms CPU, "
              f"{1e3 * row['median_thread_cpu_after_capsule_render_s']:.1f} ms of the thread, "
              f"{1e3 * row['median_wall_after_capsule_render_s']:.1f} ms wall")


STUDIES = ("resolution", "faults", "mistakes", "time", "candidates")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="few cases per point (a smoke run into out/benchmarks/)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cases", type=int, help="cases per point instead of each study's default")
    parser.add_argument("--pixel-sizes", type=float, nargs="+", help="pixel sizes [m] of the resolution study "
                        "(default 0.1-1 mm) or of the faults and mistakes studies (default 0.25 and 0.4 mm)")
    parser.add_argument("--renderers", nargs="+", choices=list(RENDERERS), default=list(RENDERERS))
    parser.add_argument("--kinds", nargs="+", choices=list(MISTAKE_KINDS), help="the mistake study's kinds (default: all)")
    parser.add_argument("--conditions", nargs="+", choices=list(CONDITIONS), default=["uncalibrated"],
                        help="the mistake study's conditions (default: uncalibrated)")
    parser.add_argument("--replot", action="store_true", help="redraw the figures from the JSON written before")
    parser.add_argument("--only", nargs="+", choices=STUDIES, help="rerun these studies into the JSON written before "
                        "(the resolution study keeps the rows of the pixel sizes not rerun)")
    args = parser.parse_args()
    folder = QUICK_OUTPUT if args.quick else FIGURES
    path = folder / "image_estimation.json"
    if args.replot:
        results = json.loads(path.read_text())
        plot(results, folder / "image_estimation.png")
        report(results)
        return
    table = load_table()
    scale = 0.1 if args.quick else 1.0
    count = lambda n: args.cases or max(2, int(n * scale))  # noqa: E731
    started = time.perf_counter()
    rng = lambda study: np.random.default_rng([args.seed, study])  # noqa: E731  (each study draws on its own)
    sizes = args.pixel_sizes
    studies = {
        "resolution": ("angle accuracy against resolution",
                       lambda: resolution_study(table, rng(0), count(40), sizes or RESOLUTION_PIXELS, args.renderers)),
        "faults": ("image faults", lambda: fault_study(table, rng(1), count(20), sizes or PIXELS, args.renderers)),
        "mistakes": ("assembly mistakes", lambda: mistake_study(table, rng(2), count(60), sizes or PIXELS, args.kinds,
                                                                args.conditions, args.renderers)),
        "time": ("time per image", lambda: time_study(table, rng(3), count(20))),
        "candidates": ("recall and time against the candidates refined", lambda: candidate_study(table, args.seed, count(20))),
    }
    chosen = args.only or list(STUDIES)
    results = {"seed": args.seed, "quick": args.quick, "tolerance_deg": TOLERANCE_DEG,
               "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count()}}
    for number, name in enumerate(chosen, start=1):
        title, run = studies[name]
        print(f"[{number}/{len(chosen)}] {title}")
        load = [round(v, 2) for v in os.getloadavg()]
        results[name] = run()
        results["machine"][f"{name}_load"] = {"before": load, "after": [round(v, 2) for v in os.getloadavg()]}
    folder.mkdir(parents=True, exist_ok=True)
    if args.only and path.exists():  # merged into the file as it is now, so that several --only runs may share it
        written = json.loads(path.read_text())
        if "resolution" in chosen and "resolution" in written:  # the rows of the sizes not rerun are kept
            rerun = {(row["pixel_size_m"], row["renderer"]) for row in results["resolution"]["rows"]}
            kept = [row for row in written["resolution"]["rows"] if (row["pixel_size_m"], row["renderer"]) not in rerun]
            results["resolution"]["rows"] = sorted(kept + results["resolution"]["rows"],
                                                   key=lambda row: (row["pixel_size_m"], row["renderer"]))
        written.update({name: results[name] for name in chosen})
        written.setdefault("machine", {}).update(results["machine"])
        results = written
    results["total_s"] = time.perf_counter() - started
    path.write_text(json.dumps(results, indent=1))
    plot(results, folder / "image_estimation.png")
    report(results)
    print(f"wrote {path} and the figures in {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
