"""Design optimizers: the paper's particle swarm and a prefix branch and bound (certified for fingers)."""
from planner.optimize.exact import solve_exact
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
    "solve_pso",
]
