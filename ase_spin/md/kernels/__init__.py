"""The compiled inner loops of the integrators, by what they do: the spherical
midpoint update (midpoint), the solvers' convergence test and Anderson mixing
(anderson), the midpoint solvers (solvers), the lattice kick and drift
(lattice), the midpoint predictor (predictor), and the state's commit and checks
(state). This package's namespace holds them all."""

from .midpoint import (CONVERGED, ROUNDOFF, NOT_CONVERGED, MEMORY, MAX_TURN, BLOCK, update_row,
                       local_midpoint, local_midpoint_direction, end_points_of_rows, pair_field_row,
                       coloured_spins, coloured_sweep)
from .anderson import after_sweep, anderson_mix, anderson_mix_serial
from .solvers import (NO_FIELD, midpoint_solve, midpoint_solve_half, midpoint_update, end_points,
                      linear_field_and_form, midpoint_solve_operators)
from .lattice import drift, kick, kick_drift
from .predictor import (PREDICTOR_DEPTH, LEAST_SQUARES_DEGREE, EXACT_ORDERS, COEFFICIENTS,
                        LOW_ORDER_COEFFICIENTS, newest_first, extrapolate, increment,
                        extrapolate_rows, max_abs_difference, best_extrapolation_order,
                        difference_table, best_order_rows)
from .state import same, same_rows, commit_state, first_nonfinite_row

__all__ = ["CONVERGED", "ROUNDOFF", "NOT_CONVERGED", "MEMORY", "MAX_TURN", "BLOCK", "update_row",
           "local_midpoint", "local_midpoint_direction", "end_points_of_rows",
           "pair_field_row", "coloured_spins", "coloured_sweep", "after_sweep",
           "anderson_mix", "anderson_mix_serial", "NO_FIELD", "midpoint_solve",
           "midpoint_solve_half", "midpoint_update", "end_points",
           "linear_field_and_form", "midpoint_solve_operators", "drift", "kick",
           "kick_drift", "PREDICTOR_DEPTH", "LEAST_SQUARES_DEGREE", "EXACT_ORDERS",
           "COEFFICIENTS", "LOW_ORDER_COEFFICIENTS", "newest_first", "extrapolate",
           "increment", "extrapolate_rows", "max_abs_difference",
           "best_extrapolation_order", "difference_table", "best_order_rows", "same",
           "same_rows", "commit_state", "first_nonfinite_row"]
