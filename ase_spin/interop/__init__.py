"""Other programs' formats: LAMMPS SPIN decks and dumps, TB2J exchange
parameters, pair files, magnetic symmetry and neighbour shells from spglib."""

from .lammps import write_lammps
from .lammps_dump import read_lammps_spin_dump
from .symmetry import magnetic_symmetry, neighbor_shells
from .pair_file import read_pairs, write_pairs
from .tb2j import read_tb2j, read_tb2j_pairs

__all__ = ["write_lammps", "read_lammps_spin_dump", "magnetic_symmetry", "neighbor_shells",
           "read_tb2j", "read_tb2j_pairs", "read_pairs", "write_pairs"]
