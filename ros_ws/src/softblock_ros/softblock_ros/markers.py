"""RViz markers of an assembly's predicted shape: one tube (LINE_STRIP) per block along the centerline.

Blocks are coloured by NiTi rod diameter (viridis over the table's range: thin = dark, thick = yellow);
a block driven beyond its safe voltage is drawn red. No rclpy import.
"""
from __future__ import annotations

import numpy as np
from matplotlib import colormaps
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from planner.kinematics import BLOCK_RADIUS

from .conversions import points_msg

INVALID_COLOR = ColorRGBA(r=1.0, g=0.0, b=0.0, a=1.0)
COLORMAP = colormaps["viridis"]


def diameter_color(rod_diameter: float, smallest: float, largest: float) -> ColorRGBA:
    fraction = (rod_diameter - smallest) / (largest - smallest) if largest > smallest else 0.5
    r, g, b, _ = COLORMAP(float(np.clip(fraction, 0.0, 1.0)))
    return ColorRGBA(r=float(r), g=float(g), b=float(b), a=1.0)


def assembly_markers(assembly, shapes: dict, table, header) -> MarkerArray:
    """Markers for ``shapes`` (chain name -> ChainShape in the assembly frame), one namespace per chain.

    The array starts with DELETEALL so blocks of a previous, longer assembly disappear.
    """
    diameters = np.asarray(table.rod_diameter)
    smallest, largest = float(diameters.min()), float(diameters.max())
    markers = [Marker(header=header, action=Marker.DELETEALL)]
    for chain in assembly.chains:
        shape = shapes[chain.name]
        samples = shape.samples_per_block
        chain_diameters = diameters[table.index_of(np.array(chain.design_ids))]
        for i, (rod_diameter, valid) in enumerate(zip(chain_diameters, shape.valid)):
            marker = Marker(header=header, ns=chain.name, id=i, type=Marker.LINE_STRIP, action=Marker.ADD)
            marker.pose.orientation.w = 1.0
            marker.scale.x = 2.0 * BLOCK_RADIUS
            marker.color = diameter_color(rod_diameter, smallest, largest) if valid else INVALID_COLOR
            marker.points = points_msg(shape.points[i * samples : (i + 1) * samples + 1])
            markers.append(marker)
    return MarkerArray(markers=markers)
