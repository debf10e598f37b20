"""The compiled inner loops of the integrators, by what they do: the spherical
midpoint update (midpoint), the solvers' convergence test and Anderson mixing
(anderson), the midpoint solvers (solvers), the lattice kick and drift
(lattice), the midpoint predictor (predictor), and the state's commit and checks
(state). This package's namespace holds them all."""

from .anderson import after_sweep, anderson_mix, anderson_mix_serial
from .lattice import drift, kick, kick_drift
from .midpoint import (BLOCK, CONVERGED, MAX_TURN, MEMORY, NOT_CONVERGED, ROUNDOFF, coloured_spins,
                       coloured_sweep, end_points_of_rows, local_midpoint, local_midpoint_direction,
                       pair_field_row, update_row)
from .predictor import (COEFFICIENTS, EXACT_ORDERS, LEAST_SQUARES_DEGREE, LOW_ORDER_COEFFICIENTS,
                        PREDICTOR_DEPTH, best_extrapolation_order, best_order_rows,
                        difference_table, extrapolate, extrapolate_rows, increment,
                        max_abs_difference, newest_first)
from .solvers import (NO_FIELD, NO_ORDER, end_points, linear_field_and_form,
                      midpoint_solve, midpoint_solve_half, midpoint_solve_held,
                      midpoint_solve_operators, midpoint_update)
from .state import commit_state, first_nonfinite_row, same, same_rows

__all__ = ["CONVERGED", "ROUNDOFF", "NOT_CONVERGED", "MEMORY", "MAX_TURN", "BLOCK", "update_row",
           "local_midpoint", "local_midpoint_direction", "end_points_of_rows",
           "pair_field_row", "coloured_spins", "coloured_sweep", "after_sweep",
           "anderson_mix", "anderson_mix_serial", "NO_FIELD", "NO_ORDER", "midpoint_solve",
           "midpoint_solve_half", "midpoint_update", "end_points",
           "linear_field_and_form", "midpoint_solve_operators", "midpoint_solve_held", "drift", "kick",
           "kick_drift", "PREDICTOR_DEPTH", "LEAST_SQUARES_DEGREE", "EXACT_ORDERS",
           "COEFFICIENTS", "LOW_ORDER_COEFFICIENTS", "newest_first", "extrapolate",
           "increment", "extrapolate_rows", "max_abs_difference",
           "best_extrapolation_order", "difference_table", "best_order_rows", "same",
           "same_rows", "commit_state", "first_nonfinite_row"]
