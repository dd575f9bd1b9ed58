"""Per-frame blendshape weights: the exact batched solver and its variants."""

from fit.solve.weights import WeightSolution, as_smoothness, solve_weights

__all__ = ["WeightSolution", "solve_weights", "as_smoothness"]
