"""Solving the SpiderMatch ILP: the HiGHS layer and solving strategies."""

from spidermatch.solve.highs import SolveResult, SolverOptions, solve_model

__all__ = ["SolveResult", "SolverOptions", "solve_model"]
