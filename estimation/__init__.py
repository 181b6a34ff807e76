"""Block angles and assembly mistakes estimated from a side-view silhouette of a chain (no ROS).

See docs/estimation.md.
"""
from estimation.calibrate import CalibrationImage, CalibrationResult, calibrate_chain
from estimation.estimate import BlockEstimate, ChainEstimate, EstimateOptions, Mistake, Status, estimate_chain
from estimation.hypotheses import MistakeKind
from estimation.view import ImagePose

__all__ = [
    "BlockEstimate",
    "CalibrationImage",
    "CalibrationResult",
    "ChainEstimate",
    "EstimateOptions",
    "ImagePose",
    "Mistake",
    "MistakeKind",
    "Status",
    "calibrate_chain",
    "estimate_chain",
]
