"""Symmetry of a crystal with spins, from spglib: neighbour shells for
assigning exchange per shell, and the magnetic space group of a spin
configuration.

- :func:`neighbor_shells` — around each symmetry-inequivalent magnetic site,
  the shells of magnetic neighbours (distance, multiplicity, and which pairs
  (i, j, lattice image) the space group makes equivalent);
- :func:`magnetic_symmetry` — the magnetic space group (UNI number, BNS and
  OG numbers, type) of the moments an Atoms carries.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import spglib
from ase.neighborlist import primitive_neighbor_list
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..terms.tabulated import ShellExchange
from ..validate import positive_scalar, real_array

__all__ = ["neighbor_shells", "NeighborShells", "Shell", "magnetic_symmetry",
           "MagneticSymmetry"]


def _spglib(what, function, *args, **kwargs):
    """Call a spglib function: its result, or ValueError naming ``what`` and
    spglib's reason, under either of spglib's error conventions (None and a
    message, or an exception; the first warns of its deprecation, which is
    spglib's business, not the user's)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            result = function(*args, **kwargs)
            reason = spglib.get_error_message() if result is None else ""
    except Exception as err:  # spglib.error.SpglibError, or bad input to its C part
        result, reason = None, str(err)
    if result is None:
        raise ValueError(f"{what}: spglib found no symmetry ({reason}); check the positions "
                         "(and moments), or change symprec")
    return result


#: Atoms further than this many cell lengths from the unit cell are refused:
#: spglib reduces fractional coordinates to [0, 1), and beyond this their
#: rounding error approaches the tolerances (wrap the positions first).
MAX_CELLS_AWAY = 1e6

#: The most (pair, symmetry operation) rows :func:`neighbor_shells` builds: the
#: pairs within ``rmax`` (estimated from the density before any is listed)
#: times the space group's operations plus one. Each row takes 40 bytes, and
#: sorting them several times that.
MAX_PAIR_ROWS = 5_000_000


def _check_crystal(atoms, what, symprec):
    """Refuse what spglib cannot take: no atoms, a non-periodic or flat cell,
    NaN/inf (spglib's C code crashes the interpreter on them) and positions so
    far from the cell that their fractional parts are rounding noise on the
    scale of ``symprec``. Returns (cell, fractional positions)."""
    if len(atoms) == 0:
        raise ValueError(f"{what}: the Atoms are empty")
    if not atoms.pbc.all():
        raise ValueError(f"{what} needs a crystal: periodic in all three directions "
                         f"(pbc = {atoms.pbc.tolist()})")
    cell = real_array(atoms.cell.array, f"{what}: the cell", shape=(3, 3))
    if not np.isfinite(cell).all():
        raise ValueError(f"{what}: the cell has non-finite entries: {cell.tolist()}")
    positions = real_array(atoms.positions, f"{what}: the positions", shape=(len(atoms), 3))
    bad = np.flatnonzero(~np.isfinite(positions).all(axis=1))
    if len(bad):
        raise ValueError(f"{what}: the position of atom {bad[0]} is not finite: "
                         f"{positions[bad[0]].tolist()}")
    volume = abs(np.linalg.det(cell))
    if not (volume >= 1e-12 and np.isfinite(volume)):
        raise ValueError(f"{what}: the cell has no volume (pbc=True needs a cell), or its "
                         f"volume overflows: {cell.tolist()}")
    frac = np.linalg.solve(cell.T, positions.T).T
    far = np.abs(frac).max(axis=1)
    k = int(np.argmax(far))
    # the rounding of the fractional coordinate, in Å, and of the position itself
    rounding = max(float(np.spacing(far[k])) * float(np.linalg.norm(cell, axis=1).max()),
                   float(np.spacing(np.abs(positions).max())))
    if not far[k] <= MAX_CELLS_AWAY or not rounding <= 0.01 * symprec:
        raise ValueError(
            f"{what}: atom {k} lies {far[k]:.3g} cell lengths from the unit cell (at most "
            f"{MAX_CELLS_AWAY:g}, and its coordinates' rounding, {rounding:.2g} Å, must stay "
            f"below symprec/100 = {0.01 * symprec:.2g} Å): wrap the positions into the cell "
            f"(atoms.wrap()) first")
    return cell, frac


def _kinds(atoms):
    """spglib's atom types: atomic number and tag together, so that atoms of one
    element can be told apart (sublattices) by giving them different tags."""
    pairs = np.column_stack([atoms.numbers, atoms.get_tags()])
    _, kinds = np.unique(pairs, axis=0, return_inverse=True)
    return kinds.ravel().astype(np.intc) + 1


def _magnetic_sites(atoms, sites):
    if sites is not None:
        idx = np.asarray(sites)
        if idx.dtype == bool:
            idx = np.nonzero(idx)[0]
        idx = np.unique(idx.astype(int))
        if len(idx) == 0 or idx.min() < 0 or idx.max() >= len(atoms):
            raise ValueError(f"sites must be atom indices in 0..{len(atoms) - 1}")
        return idx
    m = atoms.get_initial_magnetic_moments()
    mag = np.abs(m) if m.ndim == 1 else np.linalg.norm(m, axis=1)
    if mag.any():
        return np.nonzero(mag > 0.0)[0]
    return np.arange(len(atoms))


def _atom_map(frac, kinds, rot, trans, cell, symprec):
    """For one operation x → R x + t: the atom a' each atom a goes to and the
    lattice vector L_a with R f_a + t = f_{a'} + L_a."""
    moved = frac @ rot.T + trans
    diff = moved[:, None, :] - frac[None, :, :]
    lat = np.rint(diff)
    dist = np.linalg.norm((diff - lat) @ cell, axis=2)
    dist[kinds[:, None] != kinds[None, :]] = np.inf
    target = np.argmin(dist, axis=1)
    if dist[np.arange(len(frac)), target].max() > 4.0 * symprec + 1e-8:
        raise RuntimeError("an operation spglib reported does not map the atoms onto each other "
                           "within symprec")
    return target, lat[np.arange(len(frac)), target].astype(np.int64)


def _canonical(i, j, S):
    """Unordered pairs as rows (a, b, S): (i, j, S) and (j, i, −S) are one pair."""
    swap = (j < i) | ((j == i) & _lex_negative(S))
    a = np.where(swap, j, i)
    b = np.where(swap, i, j)
    S = np.where(swap[:, None], -S, S)
    return np.column_stack([a, b, S])


def _lex_negative(S):
    """S < 0 lexicographically (first non-zero component negative)."""
    first = np.argmax(S != 0, axis=1)
    return S[np.arange(len(S)), first] < 0


@dataclass
class Shell:
    """One symmetry class of neighbours of a site.

    ``index`` numbers the distinct distances around the site (1 = nearest);
    ``orbit`` tells apart classes at one distance that the space group does
    not relate (0 when the distance has a single class). ``pairs`` holds one
    row (i, j, n1, n2, n3) per neighbour: atom i = ``site``, atom j in the
    image shifted by n1 a1 + n2 a2 + n3 a3; all are equivalent by the space
    group (together with the equivalent pairs around the sites equivalent to
    ``site``).
    """

    site: int
    species: tuple
    index: int
    orbit: int
    distance: float
    multiplicity: int
    pairs: np.ndarray = field(repr=False)

    @property
    def label(self):
        return f"{self.index}{'abcdefghijklmnopqrstuvwxyz'[self.orbit - 1]}" if self.orbit \
            else str(self.index)


class NeighborShells:
    """The neighbour shells of a crystal's inequivalent magnetic sites (see
    :func:`neighbor_shells`). Iterate for :class:`Shell` entries; ``print`` it
    for a table."""

    def __init__(self, shells, sites, equivalent, spacegroup, rmax, symbols, tol=1e-4):
        self.tol = tol
        self.shells = shells
        self.sites = sites
        self.equivalent = equivalent
        self.spacegroup = spacegroup
        self.rmax = rmax
        self._symbols = symbols

    def __iter__(self):
        return iter(self.shells)

    def __len__(self):
        return len(self.shells)

    def __getitem__(self, k):
        return self.shells[k]

    def of(self, site):
        """The shells around ``site`` (any atom: its representative's)."""
        rep = self.equivalent[site]
        return [s for s in self.shells if s.site == rep]

    def distances(self, species=None):
        """Distinct shell distances (Å), sorted, over all sites; only those of
        the species pair ``species`` (e.g. ("Fe", "Fe")) when given."""
        d = [s.distance for s in self.shells
             if species is None or s.species == tuple(sorted(species))]
        return _distinct(np.array(d), self.tol)

    def multiplicities(self, site=None):
        """Neighbours per distance around ``site`` (default: the first
        inequivalent site): [z_1, z_2, ...] with orbits at one distance summed."""
        site = self.sites[0] if site is None else self.equivalent[site]
        out = []
        for s in self.of(site):
            if s.orbit <= 1:
                out.append(s.multiplicity)
            else:
                out[-1] += s.multiplicity
        return out

    def exchange(self, J, tol=0.1, offset=False):
        """A :class:`~ase_spin.ShellExchange` with ``J[n]`` (eV) on the (n+1)-th
        distinct shell distance: J a sequence (one species pair in the table)
        or a mapping from species pairs to sequences. Shells beyond the values
        given get no exchange."""
        pairs = sorted({s.species for s in self.shells})
        if not isinstance(J, dict):
            if len(pairs) != 1:
                raise ValueError(f"the table has several species pairs {pairs}: give J as a "
                                 "mapping from species pairs to lists")
            J = {pairs[0]: J}
        table = {}
        for key, values in J.items():
            key = tuple(sorted(key.split("-") if isinstance(key, str) else key))
            d = self.distances(key)
            values = real_array(values, f"J for {key[0]}-{key[1]}")
            if values.ndim != 1 or len(values) > len(d):
                raise ValueError(f"J for {key[0]}-{key[1]}: {len(values)} values for "
                                 f"{len(d)} shells within {self.rmax} Å")
            table[key] = list(zip(d[:len(values)], values))
        for key in pairs:
            table.setdefault(key, None)
        return ShellExchange(table, tol=tol, offset=offset)

    def __repr__(self):
        return (f"NeighborShells({self.spacegroup}, {len(self.sites)} inequivalent site(s), "
                f"{len(self.shells)} shells within {self.rmax} Å)")

    def __str__(self):
        lines = [f"Neighbour shells within {self.rmax:g} Å, space group {self.spacegroup}",
                 f"{'site':>5} {'pair':>8} {'shell':>6} {'distance/Å':>11} {'neighbours':>10}"
                 f"   first neighbour (j, image)"]
        for s in self.shells:
            i, j, *n = s.pairs[0]
            lines.append(f"{s.site:>5} {'-'.join(s.species):>8} {s.label:>6} {s.distance:>11.5f} "
                         f"{s.multiplicity:>10}   ({j}, ({n[0]}, {n[1]}, {n[2]}))")
        return "\n".join(lines)


def _distinct(d, tol=1e-4):
    d = np.sort(np.asarray(d, dtype=float))
    if len(d) == 0:
        return d
    keep = np.concatenate([[True], np.diff(d) > tol])
    return d[keep]


def _check_size(natoms, volume, rmax, radius, operations):
    """Refuse an ``rmax`` whose pairs within ``radius`` (estimated from the
    density, natoms² 4πr³/3V, before any is listed) times ``operations``
    exceed :data:`MAX_PAIR_ROWS`."""
    with np.errstate(over="ignore"):
        pairs = natoms * (natoms / volume) * (4.0 / 3.0) * np.pi * np.float64(radius) ** 3
    if not pairs * operations <= MAX_PAIR_ROWS:
        per = f" × {operations} symmetry operations" if operations > 1 else ""
        raise ValueError(
            f"neighbor_shells: rmax = {rmax:g} Å takes in about {pairs:.3g} pairs{per} "
            f"({natoms} atoms in {volume:.4g} Å³), more than the {MAX_PAIR_ROWS:.3g} rows "
            f"neighbor_shells builds at most: choose a smaller rmax")


def neighbor_shells(atoms, rmax, symprec=1e-5, sites=None):
    """Neighbour shells of a crystal by symmetry, for assigning exchange per shell.

    ``atoms``: a periodic crystal (its unit cell: shells are a property of the
    crystal, and a supercell only repeats them). Magnetic sites are the atoms
    with non-zero ``initial_magmoms`` (all atoms if none has one), or
    ``sites`` (indices or a mask). Atoms of one element with different tags
    are treated as different kinds (sublattices).

    The space group comes from ``spglib.get_symmetry_dataset`` with
    ``symprec`` (Å). Two pairs (i, j + n) are equivalent when an operation
    x → R x + t of the group maps one onto the other, as unordered pairs
    (J_ij = J_ji). Around each inequivalent magnetic site, the neighbours
    within ``rmax`` (Å) fall into classes of equivalent pairs: a
    :class:`Shell` each, numbered by distance; classes at the same distance
    that no operation relates are listed apart (``orbit`` a, b, ...), e.g.
    the in-plane and out-of-plane nearest neighbours of hcp.

    Refused with a ValueError: NaN/inf in the cell or positions; an atom more
    than :data:`MAX_CELLS_AWAY` cell lengths from the unit cell (or so far that
    the rounding of its coordinates reaches symprec/100: wrap the positions
    first); an ``rmax`` whose pairs (estimated from the density) times the
    space group's operations exceed :data:`MAX_PAIR_ROWS`.
    """
    rmax = positive_scalar(rmax, "neighbor_shells rmax")
    symprec = positive_scalar(symprec, "neighbor_shells symprec")
    cell, frac = _check_crystal(atoms, "neighbor_shells", symprec)
    kinds = _kinds(atoms)
    magnetic = _magnetic_sites(atoms, sites)
    # a margin beyond rmax, so that a shell at rmax is found whole
    margin = max(1e-3, 100.0 * symprec)
    _check_size(len(atoms), abs(np.linalg.det(cell)), rmax, rmax + margin, 1)
    data = _spglib("neighbor_shells", spglib.get_symmetry_dataset, (cell, frac, kinds),
                   symprec=symprec)
    _check_size(len(atoms), abs(np.linalg.det(cell)), rmax, rmax + margin,
                len(data.rotations) + 1)
    is_mag = np.zeros(len(atoms), bool)
    is_mag[magnetic] = True
    i, j, S, d = primitive_neighbor_list("ijSd", atoms.pbc, cell, atoms.positions,
                                         rmax + margin, self_interaction=False)
    keep = is_mag[i] & is_mag[j]
    i, j, S, d = i[keep], j[keep], S[keep].astype(np.int64), d[keep]
    if len(i) == 0:
        raise ValueError(f"no pair of magnetic sites within rmax = {rmax} Å")

    # classes of equivalent unordered pairs: connect each pair to its images
    # under every operation (images beyond the list get ids of their own)
    rows = [_canonical(i, j, S)]
    for R, t in zip(data.rotations, data.translations):
        amap, L = _atom_map(frac, kinds, R, t, cell, symprec)
        rows.append(_canonical(amap[i], amap[j], L[j] + S @ R.T - L[i]))
    allrows = np.concatenate(rows)
    _, ids = np.unique(allrows, axis=0, return_inverse=True)
    ids = ids.ravel()
    n = len(i)
    edges_from = np.tile(ids[:n], len(rows) - 1)
    edges_to = ids[n:]
    size = int(ids.max()) + 1
    graph = coo_matrix((np.ones(len(edges_to)), (edges_from, edges_to)), shape=(size, size))
    _, comp = connected_components(graph, directed=False)
    orbit_of = comp[ids[:n]]

    symbols = atoms.get_chemical_symbols()
    equivalent = np.asarray(data.equivalent_atoms)
    same = max(1e-4, 2.0 * symprec)  # distances equal within this are one
    reps = np.unique(equivalent[magnetic])
    shells = []
    for site in reps:
        mine = (i == site) & (d <= rmax + 1e-8)
        classes = np.unique(orbit_of[mine])
        entries = []
        for c in classes:
            sel = mine & (orbit_of == c)
            entries.append((float(d[sel].mean()), int(c), np.nonzero(sel)[0]))
        entries.sort(key=lambda e: (e[0], tuple(S[e[2][0]]), j[e[2][0]]))
        dist = _distinct([e[0] for e in entries], same)
        for dk in dist:
            at = [e for e in entries if abs(e[0] - dk) <= same]
            for o, (dd, _, sel) in enumerate(at):
                pairs = np.column_stack([i[sel], j[sel], S[sel]])
                order = np.lexsort((pairs[:, 4], pairs[:, 3], pairs[:, 2], pairs[:, 1]))
                shells.append(Shell(
                    site=int(site),
                    species=tuple(sorted((symbols[site], symbols[int(j[sel][0])]))),
                    index=int(np.searchsorted(dist, dk) + 1),
                    orbit=(o + 1) if len(at) > 1 else 0,
                    distance=dd, multiplicity=len(sel), pairs=pairs[order]))
    spacegroup = f"{data.international} (#{data.number})"
    return NeighborShells(shells, [int(r) for r in reps], equivalent, spacegroup, rmax, symbols,
                          tol=same)


@dataclass
class MagneticSymmetry:
    """The magnetic space group of a spin configuration (from spglib).

    ``uni_number``: the group's number in spglib's unified (UNI) numbering;
    ``bns_number`` and ``og_number``: its Belov–Neronova–Smirnova and
    Opechowski–Guccione numbers ("139.537"); ``number``: the ITA
    space-group number in the BNS symbol (its first part); ``type``: I (colourless: no operation reverses
    time), II (grey: time reversal alone is one: no moments), III (half the
    rotations come with time reversal), IV (a translation comes with time
    reversal: the magnetic cell is larger than the crystal's); ``operations``:
    (rotations, translations, time_reversals) in the Atoms' cell;
    ``equivalent_atoms``: the atom each is equivalent to. spglib gives no
    BNS symbol (such as I4/mm'm'); look the BNS number up in the Bilbao
    Crystallographic Server's tables for it.
    """

    uni_number: int
    bns_number: str
    og_number: str
    number: int
    type: int
    operations: tuple = field(repr=False)
    equivalent_atoms: np.ndarray = field(repr=False)

    def __str__(self):
        return (f"magnetic space group BNS {self.bns_number} (OG {self.og_number}, "
                f"UNI {self.uni_number}), type {'I II III IV'.split()[self.type - 1]}, "
                f"{len(self.operations[0])} operations")


def magnetic_symmetry(atoms, symprec=1e-5, mag_symprec=None):
    """The magnetic space group of the moments ``atoms`` carries.

    Moments: ``initial_magmoms`` — (N, 3) vectors (what
    :func:`ase_spin.set_spins` stores; treated as axial vectors) or (N,)
    collinear values. Found with ``spglib.get_magnetic_symmetry_dataset``;
    ``symprec`` (Å) for positions, ``mag_symprec`` (μB) for moments (default:
    ``symprec``). Atoms with different tags count as different kinds.
    Cells and positions are checked as in :func:`neighbor_shells`.
    """
    symprec = positive_scalar(symprec, "magnetic_symmetry symprec")
    _check_crystal(atoms, "magnetic_symmetry", symprec)
    mag_symprec = -1.0 if mag_symprec is None else positive_scalar(
        mag_symprec, "magnetic_symmetry mag_symprec")
    m = np.array(atoms.get_initial_magnetic_moments(), dtype=float)
    if not np.isfinite(m).all():
        raise ValueError("magnetic_symmetry: the magnetic moments must be finite")
    cell = (atoms.cell.array, atoms.get_scaled_positions(wrap=False), _kinds(atoms), m)
    data = _spglib("magnetic_symmetry", spglib.get_magnetic_symmetry_dataset, cell,
                   is_axial=True if m.ndim == 2 else None, symprec=symprec,
                   mag_symprec=mag_symprec)
    kind = _spglib("magnetic_symmetry", spglib.get_magnetic_spacegroup_type, data.uni_number)
    return MagneticSymmetry(
        uni_number=int(data.uni_number), bns_number=str(kind.bns_number),
        og_number=str(kind.og_number), number=int(kind.number), type=int(kind.type),
        operations=(np.array(data.rotations), np.array(data.translations),
                    np.array(data.time_reversals)),
        equivalent_atoms=np.array(data.equivalent_atoms))
