"""Hand a scene to LAMMPS SPIN, and read its trajectories back.

:func:`write_lammps` writes what ``mpirun lmp -in in.spin`` needs on a
cluster: a data file (``atom_style spin``), the input deck with the
Hamiltonian (each term gives its own LAMMPS form, :meth:`Term.lammps`), the
integrator (``fix nve/spin``, thermostats), thermo output and a dump of
positions, velocities, spins, forces and magnetic forces.
:func:`~ase_spin.interop.lammps_dump.read_lammps_spin_dump` reads such dumps back as :class:`ase.Atoms` with
spins in ``initial_magmoms`` and forces, magnetic forces and energies as
calculator results, ready for ``ase.io.write('md.traj', frames)``.

Conventions (LAMMPS metal units, see docs/lammps.md): Å, ps, eV, g/mol;
velocities Å/ps (ASE's × 1000 fs); the spin of atom i is the unit direction
(spx, spy, spz) and the magnitude sp = μ_i (μB); LAMMPS's ``fm`` is B_i/ħ
(rad/ps) with its own ħ = hplanck/2π = 6.582119102e-4 eV·ps. Atom i of the
Atoms is atom ID i + 1; type k is the k-th species in alphabetical order (the
data file labels it). A cell that is not lower triangular is rotated into
LAMMPS's frame with everything that has a direction (positions, velocities,
spins, fields, axes) and rotated back on reading.
"""

from __future__ import annotations

import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from ase import units

from ..calculator import SpinLatticeCalculator
from ..constants import HBAR_LAMMPS
from ..constraints import lattice_constraints, pinned_spins
from ..conventions import PHYSICAL
from ..hamiltonian import Hamiltonian
from ..md.base import SpinLatticeDynamics
from ..md.collective import CollectivePRK
from ..md.splitting import SuzukiTrotter
from ..spins import get_moments, split_moments
from ..terms.base import Term
from ..terms.lammps_form import LammpsFix, LammpsKspace, LammpsPair, number_text, vector_text
from ..validate import integer, positive_scalar, real_array, warn_user
from .lammps_names import DECK_SPECIAL, check_names, deck_file_name, same_file
from .lammps_plugin import collective_fix_lines, find_plugin

__all__ = ["write_lammps", "LammpsTypes", "LammpsPair", "LammpsFix",
           "LammpsFiles", "LammpsIntegratorWarning", "deck_file_name", "DECK_SPECIAL"]

#: ASE time units per LAMMPS metal time unit (ps).
PS = 1000.0 * units.fs

HEADER = "ase_spin -> LAMMPS (atom_style spin)"


class LammpsIntegratorWarning(UserWarning):
    """The exported deck integrates differently from the integrator given."""


class LammpsTypes:
    """What a term's :meth:`~ase_spin.terms.base.Term.lammps` is given: the
    scene's LAMMPS atom types and frame.

    ``symbols[k]`` is the species of type k + 1; ``magnetic[k]`` whether its
    atoms carry moments (a species is all magnetic or all non-magnetic);
    ``rotation``: lab-frame vectors v are ``v @ rotation`` in LAMMPS's frame
    (:meth:`vector`); ``group(symbol)`` names the group of one species;
    ``conventions``: the scene's (:mod:`ase_spin.conventions`), which a term
    translates into LAMMPS's; ``box``: LAMMPS's lower-triangular cell (Å) and
    ``pbc`` the periodic directions (None where not known).
    """

    def __init__(self, symbols, magnetic, rotation=None, conventions=PHYSICAL, box=None,
                 pbc=None):
        self.conventions = conventions
        self.box = None if box is None else np.asarray(box, dtype=float)
        self.pbc = None if pbc is None else tuple(bool(p) for p in pbc)
        self.symbols = tuple(symbols)
        self.magnetic = tuple(bool(m) for m in magnetic)
        self.rotation = None if rotation is None else np.asarray(rotation, dtype=float)

    @property
    def ntypes(self):
        return len(self.symbols)

    def type_of(self, symbol):
        return self.symbols.index(symbol) + 1

    def group(self, symbol):
        return f"type_{symbol}"

    def pairs(self):
        """(I, J, symbol_I, symbol_J) for every pair of types I ≤ J."""
        for a in range(self.ntypes):
            for b in range(a, self.ntypes):
                yield a + 1, b + 1, self.symbols[a], self.symbols[b]

    def vector(self, v):
        """A lab-frame direction or field in LAMMPS's frame."""
        v = np.asarray(v, dtype=float)
        return v if self.rotation is None else v @ self.rotation

    def site_groups(self, value, what):
        """(group, value) for a per-species parameter of a single-site term
        (one value, or a mapping symbol -> value): one group ``all`` when every
        type is magnetic and the value is the same, else one group per
        magnetic species (LAMMPS's ``precession/spin`` acts on unit spins
        whatever their moment, so non-magnetic species must be left out)."""
        from collections.abc import Mapping

        values = {}
        for s, m in zip(self.symbols, self.magnetic):
            if not m:
                continue
            if isinstance(value, Mapping):
                if s not in value:
                    raise ValueError(f"{what}: no value for the magnetic species {s}")
                values[s] = value[s]
            else:
                values[s] = value
        if not values:
            return []
        distinct = {repr(v) for v in values.values()}
        if all(self.magnetic) and len(distinct) == 1:
            return [("all", next(iter(values.values())))]
        return [(self.group(s), v) for s, v in values.items()]


@dataclass
class LammpsFiles:
    """What :func:`write_lammps` wrote: the directory, the data file, the
    input deck, the dump and energy files the deck will write, and the
    notices (integrator differences) it issued."""

    directory: Path
    data: Path
    input: Path
    dump: Path
    energy: Path
    symbols: tuple
    notices: list

    def command(self, ranks=None):
        """The shell command that runs the deck in its directory (the directory
        and the deck's name quoted for the shell, ``ranks`` an integer >= 1)."""
        run = f"lmp -in {shlex.quote(self.input.name)}"
        if ranks is not None:
            if isinstance(ranks, bool) or not isinstance(ranks, (int, np.integer)) or ranks < 1:
                raise ValueError(f"ranks must be an integer >= 1, got {ranks!r}")
            run = f"mpirun -n {int(ranks)} {run}"
        return f"cd {shlex.quote(str(self.directory))} && {run}"


# -- the frame --------------------------------------------------------------

def _lammps_frame(cell):
    """(box, rotation): LAMMPS's lower-triangular cell and the rotation R with
    cell @ R = box (None when the cell is lower triangular already)."""
    cell = np.asarray(cell, dtype=float)
    if not np.any(cell[np.triu_indices(3, 1)]) and np.all(np.diag(cell) > 0):
        return cell.copy(), None
    if abs(np.linalg.det(cell)) < 1e-12:
        raise ValueError("write_lammps needs three non-degenerate cell vectors (LAMMPS's box); "
                         f"got cell {cell.tolist()}")
    # cell.T = Q R (QR), so cell @ Q = R.T: lower triangular
    q, r = np.linalg.qr(cell.T)
    signs = np.sign(np.diag(r))
    q = q * signs[None, :]
    box = cell @ q
    box[np.triu_indices(3, 1)] = 0.0
    if np.linalg.det(q) < 0:
        raise ValueError("write_lammps: the cell is left-handed; LAMMPS needs a right-handed "
                         "cell (reorder or negate a cell vector)")
    return box, q


# -- the Hamiltonian ------------------------------------------------------------

def _terms(hamiltonian, atoms):
    h = hamiltonian if hamiltonian is not None else atoms.calc
    if isinstance(h, SpinLatticeCalculator):
        h = h.hamiltonian
    if isinstance(h, Term):
        h = Hamiltonian([h])
    elif isinstance(h, (list, tuple)):
        h = Hamiltonian(h)
    if not isinstance(h, Hamiltonian):
        raise TypeError("write_lammps needs the Hamiltonian: atoms.calc a SpinLatticeCalculator, "
                        f"or hamiltonian= a Hamiltonian, calculator or list of terms; got {h!r}")
    return h


def _term_parts(hamiltonian, types):
    """Every term's LAMMPS form, refusals collected into one message."""
    parts, refused = [], []
    for term, name in zip(hamiltonian.terms, hamiltonian.term_names):
        try:
            form = term.lammps(types)
        except NotImplementedError as err:
            refused.append(f"- {name} ({type(term).__name__}): {err}")
            continue
        parts.append((name, form))
    if refused:
        raise NotImplementedError("these terms have no LAMMPS counterpart, so the scene "
                                  "cannot be exported:\n" + "\n".join(refused))
    return parts


def _pair_commands(parts, directory):
    pairs = [p for _, form in parts for p in form if isinstance(p, LammpsPair)]
    if not pairs:
        return []
    styles = [p.style for p in pairs]
    hybrid = len(pairs) > 1
    lines = []
    if hybrid:
        lines.append("pair_style hybrid/overlay " + " ".join(
            f"{p.style} {p.args}".strip() for p in pairs))
    else:
        lines.append(f"pair_style {pairs[0].style} {pairs[0].args}".rstrip())
    for p in pairs:
        for f in p.files:
            target = Path(directory) / Path(f).name
            if not same_file(f, target):  # the deck written next to the potential
                shutil.copy(f, target)
    for k, p in enumerate(pairs):
        # a style used twice in hybrid/overlay is named with its instance number
        name = p.style
        if styles.count(p.style) > 1:
            name = f"{p.style} {styles[:k + 1].count(p.style)}"
        for i, j, args in p.coeffs:
            lines.append(f"pair_coeff {i} {j} {name + ' ' if hybrid else ''}{args}".rstrip())
        for option in p.modify:
            lines.append(f"pair_modify {'pair ' + name + ' ' if hybrid else ''}{option}")
    return lines


def _kspace_commands(parts):
    """``kspace_style`` and its ``kspace_modify`` lines (one solver a deck)."""
    solvers = [(name, k) for name, form in parts for k in form if isinstance(k, LammpsKspace)]
    if len(solvers) > 1:
        raise ValueError("write_lammps: LAMMPS takes one kspace_style, and the terms "
                         f"{', '.join(name for name, _ in solvers)} each need one")
    return [line for _, k in solvers for line in
            [f"kspace_style {k.style} {k.args}".rstrip()]
            + [f"kspace_modify {option}" for option in k.modify]]


def _fix_commands(parts):
    lines = []
    for name, form in parts:
        fixes = [p for p in form if isinstance(p, LammpsFix)]
        for k, fx in enumerate(fixes):
            fid = name if len(fixes) == 1 else f"{name}_{k + 1}"
            lines.append(f"fix {fid} {fx.group} {fx.style} {fx.args}")
            if fx.energy:
                lines.append(f"fix_modify {fid} energy yes")
    return lines


# -- the integrator ---------------------------------------------------------------

def _integrator(dyn, timestep, lattice, notices, plugin=False):
    """(timestep in ASE units, lattice keyword, thermostat settings or None, the
    plugin path for fix spin/collective or None)."""
    if dyn is None:
        if timestep is None:
            raise ValueError("write_lammps needs the timestep: pass an integrator (dynamics=) "
                             "or timestep= (ASE time units, e.g. 0.1 * ase.units.fs)")
        if lattice not in ("moving", "frozen"):
            raise ValueError(f'lattice must be "moving" or "frozen", got {lattice!r}')
        return positive_scalar(timestep, "write_lammps timestep"), lattice, None, None
    if not isinstance(dyn, SpinLatticeDynamics):
        raise TypeError(f"write_lammps takes an ase_spin integrator, got {type(dyn).__name__}")
    if dyn.precession != "moment":
        raise ValueError("LAMMPS SPIN integrates the moment convention ds/dt = (1/ħ) B × s "
                         f"(precession=\"moment\"); this integrator has precession="
                         f"{dyn.precession!r}, a different equation of motion")
    if dyn.gyromagnetic != "lammps":
        raise ValueError("LAMMPS SPIN's precession has no 1/μ_i (gyromagnetic=\"lammps\"); this "
                         f"integrator has gyromagnetic={dyn.gyromagnetic!r}, a different equation "
                         "of motion that LAMMPS cannot run: build the scene with "
                         "SpinLatticeCalculator(..., conventions=\"lammps\") (or pass "
                         "gyromagnetic=\"lammps\" to the integrator) to export it")
    collective = isinstance(dyn, CollectivePRK) and not hasattr(dyn, "spin_damping")
    if collective and plugin is None:
        plugin = find_plugin()
    collective = collective and plugin not in (None, False)
    if hasattr(dyn, "spin_damping") and isinstance(dyn, CollectivePRK):
        notices.append("LAMMPS has no collective (CollectivePRK) integrator with heat baths (the "
                       "ase_spin plugin has no thermostat: docs/lammps.md): the deck uses fix "
                       "nve/spin with fix langevin/spin, the sequential Suzuki–Trotter "
                       "splitting; trajectories agree only in distribution")
    elif isinstance(dyn, CollectivePRK) and not collective:
        notices.append("LAMMPS has no collective (CollectivePRK) integrator without the ase_spin "
                       "plugin (build it: ase-spin build-lammps-plugin): the deck uses fix "
                       "nve/spin, the sequential Suzuki–Trotter splitting (SuzukiTrotter here); "
                       "trajectories agree only to the methods' error, O(dt²)")
    elif not (collective or isinstance(dyn, SuzukiTrotter) or hasattr(dyn, "spin_damping")):
        notices.append(f"{type(dyn).__name__} is exported as fix nve/spin (the sequential "
                       "Suzuki–Trotter splitting)")
    if dyn.order != 2 and not collective:
        notices.append(f"order {dyn.order} has no LAMMPS counterpart: the deck runs fix "
                       "nve/spin's second-order step")
    if getattr(dyn, "rotation", "cayley") != "cayley":
        notices.append("rotation=\"exact\" differs from LAMMPS's Cayley rotation of each spin; "
                       "trajectories agree to O(dt²)")
    if abs(dyn.hbar / HBAR_LAMMPS - 1.0) > 1e-12:
        notices.append(f"the integrator's ħ ({dyn.hbar / PS:.10g} eV·ps) is not LAMMPS's "
                       f"({HBAR_LAMMPS / PS:.10g} eV·ps), which the deck will use")
    thermostat = None
    if hasattr(dyn, "spin_damping"):
        T = _attr(dyn, ("temperature_K",), None)
        if T is None and getattr(dyn, "temp", None) is not None:
            T = dyn.temp / units.kB
        Ts = getattr(dyn, "spin_temperature_K", None)
        thermostat = dict(T=float(T), T_spin=float(T if Ts is None else Ts),
                          alpha=float(dyn.spin_damping),
                          friction=float(_attr(dyn, ("friction", "fr"), 0.0) or 0.0))
    return (float(dyn.dt), "frozen" if dyn.frozen_lattice else "moving", thermostat,
            plugin if collective else None)


def _check_finite_state(atoms):
    """Refuse NaN/inf in what the data file holds: positions, velocities, cell."""
    for what, values in (("positions", atoms.positions), ("velocities", atoms.get_velocities()),
                         ("cell", atoms.cell.array)):
        values = real_array(values, f"write_lammps: the {what}")
        bad = np.argwhere(~np.isfinite(values))
        if len(bad):
            where = "" if what == "cell" else f" of atom {bad[0][0]}"
            raise ValueError(f"write_lammps: the {what}{where} are not finite: "
                             f"{values[bad[0][0]].tolist()}")


def _attr(obj, names, default):
    for n in names:
        if getattr(obj, n, None) is not None:
            return getattr(obj, n)
    return default


#: The LAMMPS group of the atoms whose spins a FixSpins pins.
PINNED_GROUP = "pinned_spins"


def _id_ranges(ids):
    """LAMMPS atom IDs (sorted, unique) as ``group ... id`` arguments, runs of
    consecutive IDs as ``a:b``."""
    parts = []
    start = prev = None
    for i in [int(x) for x in ids] + [None]:
        if start is not None and i == prev + 1:
            prev = i
            continue
        if start is not None:
            parts.append(str(start) if start == prev else f"{start}:{prev}")
        start = prev = i
    return " ".join(parts)


# -- the scene ----------------------------------------------------------------------

def _scene_types(atoms, moments):
    symbols = atoms.get_chemical_symbols()
    species = sorted(set(symbols))
    masses = atoms.get_masses()
    sym = np.array(symbols)
    mass_by_type, magnetic = [], []
    for s in species:
        m = masses[sym == s]
        if not np.all(m == m[0]):
            raise ValueError(f"LAMMPS gives one mass per atom type (species); the {s} atoms have "
                             f"masses from {m.min()} to {m.max()} amu")
        mass_by_type.append(float(m[0]))
        mu = moments[sym == s]
        if np.any(mu > 0) and np.any(mu == 0):
            raise ValueError(f"some {s} atoms have moments and others none: LAMMPS's spin styles "
                             "act on the unit spins of every atom of a type, so a species must be "
                             "all magnetic or all non-magnetic (use another symbol or tag)")
        magnetic.append(bool(np.any(mu > 0)))
    return species, mass_by_type, magnetic


def _data_file(atoms, species, masses, box, rotation, unit, mu):
    n = len(atoms)
    pos = atoms.positions if rotation is None else atoms.positions @ rotation
    vel = atoms.get_velocities() * PS
    if rotation is not None:
        vel = vel @ rotation
        unit = unit @ rotation
    types = np.searchsorted(np.array(species), np.array(atoms.get_chemical_symbols())) + 1
    rot = "none" if rotation is None else vector_text(rotation.ravel())
    lines = [f"{HEADER}; types {' '.join(species)}; rotation {rot}", "",
             f"{n} atoms", f"{len(species)} atom types", ""]
    lo = np.zeros(3)
    hi = np.diag(box).copy()
    for d in range(3):
        if not atoms.pbc[d]:
            # a shrink-wrapped direction: the box must hold every atom at the start
            lo[d] = min(0.0, pos[:, d].min() - 1.0)
            hi[d] = max(hi[d], pos[:, d].max() + 1.0)
    for d, ax in enumerate("xyz"):
        lines.append(f"{number_text(lo[d])} {number_text(hi[d])} {ax}lo {ax}hi")
    if np.any(box[np.tril_indices(3, -1)]):
        lines.append(f"{number_text(box[1, 0])} {number_text(box[2, 0])} {number_text(box[2, 1])} xy xz yz")
    lines += ["", "Atom Type Labels", ""]
    lines += [f"{k + 1} {s}" for k, s in enumerate(species)]
    lines += ["", "Masses", ""]
    lines += [f"{k + 1} {number_text(m)}" for k, m in enumerate(masses)]
    lines += ["", "Atoms # spin", ""]
    # non-magnetic atoms: a unit direction LAMMPS can normalise, magnitude 0
    unit = np.where(mu[:, None] > 0, unit, [0.0, 0.0, 1.0])
    for k, (t, x, s, m) in enumerate(zip(types.tolist(), pos.tolist(), unit.tolist(),
                                         mu.tolist())):
        lines.append(f"{k + 1} {t} {vector_text(x)} {vector_text(s)} {number_text(m)}")
    lines += ["", "Velocities", ""]
    lines += [f"{k + 1} {vector_text(v)}" for k, v in enumerate(vel.tolist())]
    return "\n".join(lines) + "\n"


def write_lammps(directory, atoms, dynamics=None, *, steps=0, hamiltonian=None, timestep=None,
                 lattice="moving", dump_interval=10, thermo_interval=None, seed=12345,
                 data_name="atoms.data", input_name="in.spin", dump_name="dump.spin",
                 energy_name="energy.spin", plugin=None):
    """Write a scene as a LAMMPS SPIN run: ``directory/atoms.data`` and
    ``directory/in.spin``, to be run there with ``mpirun lmp -in in.spin``.

    Parameters
    ----------
    directory : str or path
        Created if missing; existing files of the same names are overwritten.
    atoms : ase.Atoms
        Positions, cell (any right-handed cell; rotated into LAMMPS's frame if not
        lower triangular), pbc (periodic: ``p``, else shrink-wrapped ``s``),
        masses (one per species), velocities, spins (``initial_magmoms`` (N, 3)).
        A :class:`~ase_spin.FixSpins` constraint becomes the group
        ``pinned_spins`` and ``fix pin_spins pinned_spins setforce/spin 0.0 0.0
        0.0`` (LAMMPS's dump then shows fm = 0 for those atoms); other
        constraints are refused.
    dynamics : ase_spin integrator, optional
        Its timestep, lattice mode and thermostat. SuzukiTrotter (Cayley,
        order 2) is LAMMPS's ``fix nve/spin`` step; CollectivePRK (orders 2, 4,
        6) is ``fix spin/collective`` of the ase_spin plugin (``plugin load``,
        see ``plugin``), else, and other orders, that step with a
        :class:`LammpsIntegratorWarning`;
        precession="spin" or gyromagnetic="moment" (equations LAMMPS does not
        have) are refused. An integrator with ``spin_damping`` (ase_spin's
        Langevin) adds ``fix langevin/spin T α seed`` and, with a friction,
        a lattice ``fix langevin T T 1/friction seed``.
    steps : int
        Steps the deck runs (``run steps``): an integer >= 0 (a float such as
        2.5 is refused, not truncated).
    hamiltonian : Hamiltonian, SpinLatticeCalculator or list of terms, optional
        Default ``atoms.calc``'s. Every term must have a LAMMPS form
        (``term.lammps(types)``); those without are refused, all named in one
        NotImplementedError. Its skin is the deck's ``neighbor`` skin.
    timestep : float, optional
        ASE time units, when no integrator is given (with ``lattice``): finite
        and positive. NaN/inf positions, velocities or cell are refused too.
    dump_interval, thermo_interval : int
        Steps between dump frames (and energy lines), and thermo lines
        (default: the dump interval).
    seed : int
        Seed of LAMMPS's thermostats.
    data_name, input_name, dump_name, energy_name : str
        The files' names in ``directory``, as the deck names them: plain,
        distinct names (no path separator, whitespace or control character,
        none of ``$ & # ' " ` \\ * %``: :func:`deck_file_name`); potential
        files are copied under their own names, checked alike. A name the deck
        cannot hold is a ValueError naming it, before anything is written.
    plugin : path, None or False
        For a CollectivePRK: the ase_spin LAMMPS plugin the deck loads (a path
        on the machine that runs it); None (default): the plugin built here
        (:func:`~ase_spin.interop.lammps_plugin.find_plugin`), if any, else
        ``fix nve/spin`` with a warning; False: ``fix nve/spin``.

    Returns
    -------
    LammpsFiles
        The paths, the type symbols, the notices issued; ``.command(ranks)``
        is the shell line that runs it.
    """
    steps = integer(steps, "write_lammps steps", minimum=0)
    dump_interval = integer(dump_interval, "write_lammps dump_interval", minimum=1)
    thermo_interval = dump_interval if thermo_interval is None else integer(
        thermo_interval, "write_lammps thermo_interval", minimum=1)
    seed = integer(seed, "write_lammps seed", minimum=1)
    _check_finite_state(atoms)
    if dynamics is not None and dynamics.atoms is not atoms:
        raise ValueError("write_lammps: the integrator holds other Atoms than those given")
    others = lattice_constraints(atoms)
    if others:
        raise ValueError("write_lammps: constraints have no export yet "
                         f"({', '.join(type(c).__name__ for c in others)}); remove "
                         "them, or add the matching LAMMPS fix to the deck by hand")
    pinned = pinned_spins(atoms)
    notices = []
    dt, lattice, thermostat, plugin = _integrator(dynamics, timestep, lattice, notices, plugin)
    hamiltonian = _terms(hamiltonian, atoms)
    unit, mu = split_moments(get_moments(atoms))
    species, masses, magnetic = _scene_types(atoms, mu)
    cell = atoms.cell.array.copy()
    if not atoms.pbc.any():
        cell = np.eye(3)  # no periodic direction: the box is shrink-wrapped to the atoms
    elif not atoms.pbc.all():
        if np.any(cell[~np.eye(3, dtype=bool)]):
            raise ValueError("write_lammps: a cell with tilt needs periodic boundaries in "
                             "every direction (LAMMPS triclinic boxes with non-periodic "
                             "directions are not exported)")
        for d in range(3):
            if not cell[d, d] > 0:
                cell[d, d] = 1.0  # a placeholder: shrink-wrapped to the atoms
    box, rotation = _lammps_frame(cell)
    types = LammpsTypes(species, magnetic, rotation, hamiltonian.conventions, box, atoms.pbc)
    parts = _term_parts(hamiltonian, types)
    for text in notices:
        warn_user(text, LammpsIntegratorWarning)

    names = check_names({"data_name": data_name, "input_name": input_name,
                          "dump_name": dump_name, "energy_name": energy_name}, parts)
    data_name, input_name = names["data_name"], names["input_name"]
    dump_name, energy_name = names["dump_name"], names["energy_name"]

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    data = _data_file(atoms, species, masses, box, rotation, unit, mu)
    (directory / data_name).write_text(data)

    kspace = _kspace_commands(parts)
    # a slab's k-space (kspace_modify slab) needs a fixed boundary across it
    across = "f" if any(isinstance(k, LammpsKspace) and k.slab for _, f in parts for k in f) else "s"
    boundary = " ".join("p" if p else across for p in atoms.pbc)
    deck = [f"# {HEADER}: {len(atoms)} atoms, types {' '.join(species)}",
            f"# run with: mpirun -n <ranks> lmp -in {input_name}"]
    deck += [f"# NOTE: {t}" for t in notices]
    deck += ["", "units metal", "atom_style spin",
             "# nve/spin needs the atom map; no sorting keeps the sweep order of one rank",
             "atom_modify map array sort 0 0.0", f"boundary {boundary}",
             f"read_data {data_name}", ""]
    deck += [f"group {types.group(s)} type {k + 1}" for k, s in enumerate(species)]
    if pinned is not None:
        deck.append(f"group {PINNED_GROUP} id {_id_ranges(np.flatnonzero(pinned) + 1)}")
    deck += [""] + _pair_commands(parts, directory) + kspace
    # after pair_coeff: the eam styles set each type's mass from the potential file
    # (CoAl.eam.alloy: Co 58.9332, ASE 58.933194), which would override the data file's
    deck += [f"mass {k + 1} {number_text(m)}" for k, m in enumerate(masses)]
    # the calculator's skin: LAMMPS then loops over the pairs ase_spin does (a wider one
    # only slows its steps: benchmarks/lammps_skin.py, docs/benchmarks.md)
    deck += [f"neighbor {number_text(hamiltonian.skin)} bin",
             "neigh_modify every 1 delay 0 check yes", ""]
    term_fixes = _fix_commands(parts)
    deck += term_fixes
    if thermostat is not None:
        if thermostat["friction"] > 0 and lattice == "moving":
            damp = 1.0 / thermostat["friction"] / PS
            deck.append(f"fix thermostat_lattice all langevin {number_text(thermostat['T'])} "
                        f"{number_text(thermostat['T'])} {number_text(damp)} {int(seed) + 1} zero yes")
        elif not any(line.startswith("fix ") for line in term_fixes):
            # LAMMPS (2025) refuses fix langevin/spin as a deck's first fix ("has to
            # come after all other spin fixes": it compares fix indices with 0)
            deck += ["# a zero field: fix langevin/spin may not be the first fix",
                     "fix no_field all precession/spin zeeman 0.0 0.0 0.0 1.0"]
        # langevin/spin after the precession fixes, before nve/spin (LAMMPS's rule)
        deck.append(f"fix thermostat_spin all langevin/spin {number_text(thermostat['T_spin'])} "
                    f"{number_text(thermostat['alpha'])} {int(seed)}")
    if pinned is not None:
        # FixSpins: nve/spin advances each spin in the field fm that the pair
        # styles, the precession/spin and langevin/spin fixes and then this fix
        # make (that order whatever the deck's); defined after those fixes, it
        # also zeroes the fm the dump shows (their post_force order)
        deck += [("# FixSpins: these spins keep their directions (fm = 0 in the dump, "
                  "not −∂E/∂s)"),
                 f"fix pin_spins {PINNED_GROUP} setforce/spin 0.0 0.0 0.0"]
    if plugin is None:
        deck.append(f"fix integrate all nve/spin lattice {lattice}")
    else:  # CollectivePRK's step: the ase_spin plugin (ase_spin.interop.lammps_plugin)
        deck += collective_fix_lines(dynamics, plugin, lattice)
    deck += [f"timestep {number_text(dt / PS)}", ""]
    deck += ["compute magnetisation all spin",
             "compute spin_state all property/atom sp spx spy spz fmx fmy fmz",
             "variable pe equal pe", "variable ke equal ke",
             f"fix energies all ave/time {dump_interval} 1 {dump_interval} v_pe v_ke "
             f"file {energy_name} format ' %.17g'",
             "thermo_style custom step time temp pe ke etotal press c_magnetisation[4] "
             "c_magnetisation[5] c_magnetisation[6]",
             f"thermo {thermo_interval}",
             f"dump trajectory all custom {dump_interval} {dump_name} id type xu yu zu "
             "vx vy vz c_spin_state[1] c_spin_state[2] c_spin_state[3] c_spin_state[4] "
             "fx fy fz c_spin_state[5] c_spin_state[6] c_spin_state[7]",
             "dump_modify trajectory sort id format float %.17g",
             "", f"run {steps}", ""]
    (directory / input_name).write_text("\n".join(deck))
    return LammpsFiles(directory, directory / data_name, directory / input_name,
                       directory / dump_name, directory / energy_name, tuple(species), notices)


# -- reading back -------------------------------------------------------------------
