"""Solving the SpiderMatch ILP: the HiGHS layer and solving strategies."""

from spidermatch.solve.highs import solve_model
from spidermatch.solve.types import SolveResult, SolverOptions

__all__ = ["SolveResult", "SolverOptions", "solve_model"]
