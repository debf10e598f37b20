"""Input and output: trajectories (never overwritten, recoverable after a
killed run), spins for viewers (ASE's, OVITO), progress bars."""

from .trajectories import check_trajectory_target, complete_frames, recover_trajectory
from .viewing import plot_spins, spin_colors, write_ovito_xyz

__all__ = ["check_trajectory_target", "complete_frames", "recover_trajectory",
           "plot_spins", "spin_colors", "write_ovito_xyz"]
