"""Design optimizers: the paper's particle swarm, a certified branch and bound for fingers and a prefix
branch and bound with a beam for paths."""
from planner.optimize.exact import solve_exact
from planner.optimize.finger_search import solve_finger
from planner.optimize.pso import design_costs, solve_pso
from planner.optimize.result import DesignOptimizeResult, Progress, Status
from planner.optimize.space import MAX_BLOCKS, DesignSpace, design_space

__all__ = [
    "MAX_BLOCKS",
    "DesignOptimizeResult",
    "DesignSpace",
    "Progress",
    "Status",
    "design_costs",
    "design_space",
    "solve_exact",
    "solve_finger",
    "solve_pso",
]
