"""What users measure from a run: spectra S(q, ω) and spin waves
(docs/spectra.md); observers for ``dyn.attach`` (magnetisation per sublattice,
topological charge, correlations, fluctuations, spin temperature), the
statistics behind their errors, and T_C from Binder cumulants
(docs/observables.md, docs/monte_carlo.md)."""

from .lswt import MagnonBands, magnon_bands, spin_wave_matrix
from .observers import (Fluctuations, Observer, SpinCorrelation, SpinTemperature,
                        SublatticeMagnetisation, TopologicalCharge)
from .plotting import plot_spectrum
from .qpath import QPath, q_path
from .spectra import (Spectrum, SpinSeries, StructureFactorRecorder,
                      dynamical_structure_factor, read_spin_series)
from .statistics import (Estimate, autocorrelation_time, binder_crossing, block_average,
                         blocking_levels, jackknife)
from .topology import LayerTriangulation, solid_angles, topological_charge

__all__ = ["QPath", "q_path", "MagnonBands", "magnon_bands", "spin_wave_matrix",
           "Spectrum", "SpinSeries", "StructureFactorRecorder", "dynamical_structure_factor",
           "read_spin_series", "plot_spectrum",
           "Observer", "SublatticeMagnetisation", "TopologicalCharge", "SpinCorrelation",
           "Fluctuations", "SpinTemperature", "Estimate", "block_average", "blocking_levels",
           "jackknife", "binder_crossing", "autocorrelation_time", "LayerTriangulation",
           "solid_angles", "topological_charge"]
