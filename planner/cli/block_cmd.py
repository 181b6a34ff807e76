"""`python -m planner block`: angle, stiffness, stroke and voltage limit of one block design."""
from __future__ import annotations

import math

from planner.block_model import TABLE_FIDELITY, Fidelity
from planner.materials import MATERIALS


def register(subparsers) -> None:
    parser = subparsers.add_parser("block", help="evaluate one block design with the physics model")
    parser.add_argument("--length", type=float, required=True, help="rod free length L [m]")
    parser.add_argument("--diameter", type=float, required=True, help="NiTi rod diameter D [m]")
    parser.add_argument("--prestretch", type=float, required=True, help="axial prestretch lambda_1")
    parser.add_argument("--tangential", type=float, help="tangential prestretch (default 2.5 / lambda_1)")
    parser.add_argument("--voltage", type=float, default=2400.0, help="applied voltage [V] (default: %(default)s)")
    parser.add_argument("--material", choices=sorted(MATERIALS), default="elastosil")
    parser.add_argument("--film-thickness", type=float, help="unstretched film thickness [m] (default: calibrated)")
    parser.add_argument("--permittivity", type=float, help="relative permittivity (default: material's)")
    parser.add_argument("--rod-modulus", type=float, help="NiTi Young's modulus [Pa] (default: calibrated)")
    parser.add_argument("--fidelity", choices=("closed_form", "arc", "chord"), default=TABLE_FIDELITY.kind)
    parser.add_argument("--strips", type=int, default=TABLE_FIDELITY.n_strips)
    parser.set_defaults(handler=run)


def run(args) -> int:
    from planner.block_model import BlockDesigns, BlockModel, Status
    from planner.materials import material_by_name

    designs = BlockDesigns.create(
        args.length, args.diameter, args.prestretch,
        prestretch_tangential=args.tangential,
        material=material_by_name(args.material),
        film_thickness=args.film_thickness,
        relative_permittivity=args.permittivity,
        rod_modulus=args.rod_modulus,
    )
    model = BlockModel(designs, Fidelity(args.fidelity, args.strips))
    rest, actuated = model.solve(0.0), model.solve(args.voltage)
    limit = model.voltage_limit()
    for label, result in (("0 V", rest), (f"{args.voltage:.0f} V", actuated)):
        if result.success:
            print(f"theta at {label}: {result.theta[0]:.5f} rad ({math.degrees(result.theta[0]):.2f} deg), "
                  f"stiffness {result.stiffness[0]:.4g} N m/rad")
        else:
            print(f"theta at {label}: no valid equilibrium ({Status(result.status[0]).name})")
    stroke = rest.theta[0] - actuated.theta[0]
    if math.isfinite(stroke):
        print(f"stroke: {stroke:.5f} rad ({math.degrees(stroke):.2f} deg)")
    if limit.limited_by[0] == Status.OK:
        print(f"voltage limit: none found up to {limit.voltage[0]:.0f} V")
    else:
        print(f"voltage limit: {limit.voltage[0]:.0f} V ({Status(limit.limited_by[0]).name})")
    return 0 if rest.success and actuated.success else 1
