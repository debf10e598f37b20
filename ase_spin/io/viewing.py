"""Looking at spins: colours, an OVITO-ready extended XYZ file, pictures.

``ase gui`` draws the (N, 3) ``initial_magmoms`` as arrows (View → Show
magmoms) but colours atoms only by per-atom *scalars*; OVITO reads every extxyz
column, but turns only some column names into its standard properties. The
writer here adds, next to the positions and ``initial_magmoms``:

==============  ======================  =====================================
extxyz column   OVITO property          what it holds
==============  ======================  =====================================
``dipoles``     Dipole Orientation      unit spin directions s_i (arrows)
``dipoles_mag`` Dipole Magnitude        moment magnitudes μ_i (μB)
``color``       Color                   RGB of each atom (see :func:`spin_colors`)
``vector_color`` Vector Color           the same RGB for its arrow
``spin_angle``  spin_angle (user)       angle between s_i and M (degrees)
``spin_z``      spin_z (user)           z component of s_i
==============  ======================  =====================================

and, for a frame written during a run (whose ``info`` holds them), the
magnetic forces B_i (eV) as the column ``magnetic_forces`` (user property).

``spin_angle`` and ``spin_z`` are scalars, so ``ase gui`` lists them under
View → Colors ("By user-defined ...") too: that is how to see s_z of a film
from above, where the arrows of spins along the normal have no length.
:func:`plot_spins` draws a matplotlib picture: 3D, or seen along the normal
for a flat system (:func:`film_plane`). See docs/viewing.md.
"""

from __future__ import annotations

import os

import numpy as np

from ..spins import get_moments, split_moments

__all__ = ["spin_colors", "spin_angles", "magnetization", "write_ovito_xyz",
           "ovito_pipeline", "plot_spins", "film_plane"]

#: the colour map of :func:`spin_colors`: value −1, 0, +1 (blue, white, red)
_NEGATIVE = np.array([0.23, 0.30, 0.75])
_ZERO = np.array([0.87, 0.87, 0.87])
_POSITIVE = np.array([0.71, 0.02, 0.15])
#: colour of non-magnetic atoms
NONMAGNETIC = np.array([0.55, 0.55, 0.55])

_COLOR_BY = ("angle", "x", "y", "z")


def magnetization(spins):
    """M = (1/N_m) Σ_i s_i over the magnetic atoms (zero rows are not counted);
    the zero vector if there are none."""
    magnetic = np.any(spins != 0.0, axis=1)
    n = int(magnetic.sum())
    return spins[magnetic].sum(axis=0) / n if n else np.zeros(3)


def spin_angles(spins):
    """Angle (degrees) between each unit spin s_i and the magnetisation M,
    θ_i = arccos(s_i·M/|M|); NaN for non-magnetic atoms. With |M| = 0 (no
    preferred direction) the angle is taken to +z."""
    M = magnetization(spins)
    norm = float(np.linalg.norm(M))
    axis = M / norm if norm > 0.0 else np.array([0.0, 0.0, 1.0])
    c = np.clip(spins @ axis, -1.0, 1.0)
    theta = np.degrees(np.arccos(c))
    theta[~np.any(spins != 0.0, axis=1)] = np.nan
    return theta


def spin_colors(atoms_or_spins, by="angle"):
    """RGB colours (N, 3) in [0, 1] for the spins of an Atoms (or of an (N, 3)
    array of unit spins).

    ``by="angle"``: the value v = cos θ_i = s_i·M/|M| (M the magnetisation);
    ``by="x" | "y" | "z"``: v = that component of s_i. v runs from −1 (blue)
    through 0 (light grey) to +1 (red), linearly in each channel on each half;
    non-magnetic atoms are grey (:data:`NONMAGNETIC`).
    """
    spins = _spins_of(atoms_or_spins)
    rgb = _rgb(_colour_values(spins, by))
    rgb[~np.any(spins != 0.0, axis=1)] = NONMAGNETIC
    return rgb


def _colour_values(spins, by):
    """The value in [−1, 1] that :func:`spin_colors` maps to a colour."""
    if not isinstance(by, str) or by not in _COLOR_BY:
        raise ValueError(f"colour by must be one of {_COLOR_BY}, got {by!r}")
    if by == "angle":
        v = np.cos(np.radians(np.nan_to_num(spin_angles(spins))))
    else:
        v = spins[:, "xyz".index(by)]
    return np.clip(v, -1.0, 1.0)


def _rgb(v):
    v = np.asarray(v, dtype=float)[:, None]
    return np.where(v >= 0.0, _ZERO + v * (_POSITIVE - _ZERO), _ZERO - v * (_NEGATIVE - _ZERO))


def _spins_of(x):
    if hasattr(x, "arrays"):
        return split_moments(get_moments(x))[0]
    s = np.asarray(x, dtype=float)
    if s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f"spins must have shape (N, 3), got {s.shape}")
    return s


def _frames(frames):
    from ase import Atoms

    if isinstance(frames, Atoms):
        return [frames]
    if isinstance(frames, (str, os.PathLike)):
        from ase.io import read

        return read(frames, ":")
    frames = list(frames)
    for k, f in enumerate(frames):
        if not isinstance(f, Atoms):
            raise TypeError(f"frame {k} is not an ase.Atoms: {type(f).__name__}")
    return frames


def _results(atoms):
    """The calculator results that belong to this state (energy, forces, stress):
    kept in the extxyz frame; none if the calculator's are stale or absent."""
    calc = atoms.calc
    if calc is None or not getattr(calc, "results", None):
        return {}
    try:
        if calc.check_state(atoms):
            return {}
    except Exception:  # noqa: BLE001 - a calculator that cannot tell: keep nothing
        return {}
    keep = ("energy", "free_energy", "forces", "stress")
    return {k: np.copy(v) for k, v in calc.results.items() if k in keep}


def ovito_frame(atoms, color_by="angle"):
    """A copy of ``atoms`` with the viewing columns of this module's table
    (``atoms`` itself is not changed). Needs (N, 3) ``initial_magmoms``."""
    from ase.calculators.singlepoint import SinglePointCalculator

    moments = get_moments(atoms)
    if not atoms.has("initial_magmoms") or np.ndim(atoms.arrays["initial_magmoms"]) != 2:
        raise ValueError("the atoms carry no (N, 3) initial_magmoms to show: set spins with "
                         "ase_spin.set_spins(atoms, directions, magnitudes)")
    spins, mu = split_moments(moments)
    rgb = spin_colors(spins, color_by)
    frame = atoms.copy()
    frame.arrays["dipoles"] = spins
    frame.arrays["dipoles_mag"] = mu
    frame.arrays["color"] = rgb
    frame.arrays["vector_color"] = rgb.copy()
    frame.arrays["spin_angle"] = np.nan_to_num(spin_angles(spins), nan=0.0)
    frame.arrays["spin_z"] = spins[:, 2].copy()
    # the magnetic forces of a frame written during a run (or read from a
    # .traj) as a column, not as N × 3 numbers in the comment line
    B = frame.info.pop("magnetic_forces", None)
    if B is not None and np.shape(B) == (len(frame), 3):
        frame.arrays["magnetic_forces"] = np.array(B, dtype=float)
    M = magnetization(spins)
    frame.info["magnetization"] = M
    frame.info["abs_magnetization"] = float(np.linalg.norm(M))
    results = _results(atoms)
    if results:
        frame.calc = SinglePointCalculator(frame, **results)
    return frame


def write_ovito_xyz(path, frames, color_by="angle", append=False):
    """Write spin frames as extended XYZ that OVITO (and ``ase gui``) show
    with arrows and colours.

    Parameters
    ----------
    path : str or path
        The ``.xyz`` file.
    frames : Atoms, iterable of Atoms, or str/path
        One state, several (e.g. ``ase.io.read("md.traj", ":")``), or a file
        ASE can read (every frame of it). Each needs (N, 3) ``initial_magmoms``.
    color_by : "angle" | "x" | "y" | "z"
        What the ``color`` column shows (:func:`spin_colors`).
    append : bool
        Add the frames to an existing file (a trajectory written step by step).

    Each frame gets the columns of the module table (``dipoles`` = s_i,
    ``dipoles_mag`` = μ_i, ``color``, ``vector_color``, ``spin_angle``,
    ``spin_z``; ``magnetic_forces`` where the frame's ``info`` holds them),
    the magnetisation M and |M| in its comment line, and the energy, forces
    and stress if the frame's calculator holds them for this state. The
    frames given are not changed. Returns the number of frames written.
    """
    from ase.io import write

    frames = _frames(frames)
    if not frames:
        raise ValueError("no frames to write")
    out = []
    for k, atoms in enumerate(frames):
        try:
            out.append(ovito_frame(atoms, color_by))
        except ValueError as err:
            raise ValueError(f"frame {k}: {err}") from None
    write(path, out, format="extxyz", append=append)
    return len(out)


def ovito_pipeline(path, arrow_scale=2.0, arrow_width=0.2, radius=0.35):
    """An OVITO pipeline for a file from :func:`write_ovito_xyz` with the spin
    arrows switched on (OVITO creates the Dipole Orientation arrows' visual
    element disabled), arrows ``arrow_scale`` Å long per unit spin, centred on
    the atoms, atoms of ``radius`` Å. Needs the ``ovito`` Python module
    (``pip install ovito``); the pipeline is not yet added to the scene."""
    try:
        from ovito.io import import_file
        from ovito.modifiers import ComputePropertyModifier
        from ovito.vis import VectorVis
    except ImportError as err:
        raise ImportError("ovito_pipeline needs the OVITO Python module: pip install ovito "
                          f"({err})") from None
    pipeline = import_file(str(path))
    data = pipeline.compute()
    if "Dipole Orientation" not in data.particles:
        raise ValueError(f"{str(path)!r} has no 'dipoles' column: write it with "
                         "ase_spin.write_ovito_xyz")
    vis = data.particles["Dipole Orientation"].vis
    if vis is None:  # pragma: no cover - OVITO versions without a default element
        vis = VectorVis()
    vis.enabled = True
    vis.scaling = arrow_scale
    vis.width = arrow_width
    vis.alignment = VectorVis.Alignment.Center
    # small atoms, or they hide the arrows (OVITO's per-element radii are ~1.3 Å)
    pipeline.modifiers.append(ComputePropertyModifier(output_property="Radius",
                                                      expressions=[repr(float(radius))]))
    return pipeline


def film_plane(atoms, thickness=1.0, ratio=0.1):
    """The plane of a flat system: ``(normal, e1, e2, flat)``, unit vectors
    with e1 × e2 = normal.

    The candidate normals are those of the cell's planes (a × b, b × c,
    c × a; missing cell vectors completed as ASE's ``Cell.complete`` does):
    only that of the one non-periodic direction when exactly one is
    non-periodic (a film or slab), else the one along which the positions
    spread least. The normal points to the side of the cell vector off the
    plane; e1 is the first cell vector in the plane. ``flat``: the positions
    spread along the normal by at most ``thickness`` Å, or by at most
    ``ratio`` times their smaller extent in the plane (a monolayer, a
    buckled or rattled one, or a few layers of a wide film).
    """
    cell = atoms.cell.complete().array
    pos = np.asarray(atoms.positions, dtype=float)
    periodic = np.asarray(atoms.pbc, dtype=bool)
    ks = [int(np.flatnonzero(~periodic)[0])] if (~periodic).sum() == 1 else [2, 0, 1]
    best = None
    for k in ks:
        a, b = cell[(k + 1) % 3], cell[(k + 2) % 3]
        n = np.cross(a, b)
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            continue
        n /= norm
        if cell[k] @ n < 0.0:
            n = -n
        e1 = a / np.linalg.norm(a)
        spread = float(np.ptp(pos @ n)) if len(pos) else 0.0
        if best is None or spread < best[0] - 1e-9:
            best = (spread, n, e1, np.cross(n, e1))
    spread, n, e1, e2 = best
    in_plane = min(np.ptp(pos @ e1), np.ptp(pos @ e2)) if len(pos) else 0.0
    flat = spread <= max(thickness, ratio * in_plane)
    return n, e1, e2, bool(flat)


def plot_spins(atoms, path=None, color_by=None, ax=None, arrow_length=None, view="auto"):
    """A matplotlib picture of the spins, coloured as :func:`spin_colors`.

    ``view="3d"``: a 3D quiver, an arrow s_i centred at each magnetic atom,
    non-magnetic atoms as grey points, coloured by ``color_by`` (default
    "angle"). ``view="top"``: the system seen along its normal
    (:func:`film_plane`), in-plane axes in Å: a 2D quiver of the in-plane
    part of each spin, coloured by ``color_by`` (default: the component along
    the normal, s_z for a film in the xy plane; a spin along the normal is a
    coloured dot), with a colour bar. ``view="auto"`` (default): the top
    view when the system is flat (a film), else 3D; with ``ax`` given, the
    kind of ``ax`` (3D or not) decides. ``arrow_length``: Å per unit spin
    (default 1.2 in 3D; in the top view 0.7 times the spacing of the atoms
    in the plane).

    Draws into ``ax`` or a new figure; saves to ``path`` if given. Returns
    the figure. Needs matplotlib (``pip install 'ase-spin[plot]'``)."""
    if view not in ("auto", "3d", "top"):
        raise ValueError(f'view must be "auto", "3d" or "top", got {view!r}')
    Figure = _figure_class()
    spins, _ = split_moments(get_moments(atoms))
    normal, e1, e2, flat = film_plane(atoms)
    if view == "auto":
        view = ("3d" if ax.name == "3d" else "top") if ax is not None else (
            "top" if flat else "3d")
    if ax is not None and (ax.name == "3d") != (view == "3d"):
        raise ValueError(f"view={view!r} needs {'a 3D' if view == '3d' else 'a 2D'} axes, "
                         f"got {ax.name!r} axes")
    if ax is None:
        fig = Figure(figsize=(6, 5))
        ax = fig.add_subplot(projection="3d") if view == "3d" else fig.add_subplot()
    else:
        fig = ax.figure
    if view == "3d":
        _plot_3d(ax, atoms, spins, color_by or "angle",
                 1.2 if arrow_length is None else arrow_length)
    else:
        _plot_top(fig, ax, atoms, spins, color_by, arrow_length, normal, e1, e2)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def _plot_3d(ax, atoms, spins, color_by, arrow_length):
    rgb = spin_colors(spins, color_by)
    magnetic = np.any(spins != 0.0, axis=1)
    pos = atoms.positions
    # arrows centred on the atoms, as OVITO draws them
    tail = pos - 0.5 * arrow_length * spins
    ax.quiver(*tail[magnetic].T, *(arrow_length * spins[magnetic]).T,
              colors=rgb[magnetic], arrow_length_ratio=0.35, linewidths=1.5)
    ax.scatter(*pos.T, s=6, c=np.where(magnetic[:, None], rgb, NONMAGNETIC), depthshade=True)
    ax.set_xlabel("x (Å)")
    ax.set_ylabel("y (Å)")
    ax.set_zlabel("z (Å)")
    span = np.ptp(pos, axis=0) if len(pos) else np.ones(3)
    ax.set_box_aspect(np.maximum(span, 1e-3))
    label = "cos θ to M" if color_by == "angle" else f"s_{color_by}"
    ax.set_title(f"spins, colour: {label} (red +1, blue −1)")


def _axis_name(e, fallback):
    """"x", "−y", ... when ``e`` is a Cartesian axis, else ``fallback``."""
    k = int(np.argmax(np.abs(e)))
    if abs(abs(e[k]) - 1.0) > 1e-9:
        return fallback
    return ("" if e[k] > 0 else "−") + "xyz"[k]


def _plot_top(fig, ax, atoms, spins, color_by, arrow_length, normal, e1, e2):
    from matplotlib.colors import LinearSegmentedColormap

    magnetic = np.any(spins != 0.0, axis=1)
    pos = np.asarray(atoms.positions, dtype=float)
    x, y = pos @ e1, pos @ e2
    if color_by is None:
        value = np.clip(spins @ normal, -1.0, 1.0)
        along = _axis_name(normal, None)
        label = "s·n (n the film normal)" if along is None else (
            f"s_{along}" if len(along) == 1 else f"−s_{along[1]}")
    else:
        value = _colour_values(spins, color_by)
        label = "cos θ to M" if color_by == "angle" else f"s_{color_by}"
    if arrow_length is None:
        area = np.ptp(x) * np.ptp(y) if len(pos) else 0.0
        arrow_length = 0.7 * np.sqrt(area / len(pos)) if area > 0.0 else 1.2
    cmap = LinearSegmentedColormap.from_list("spin", [_NEGATIVE, _ZERO, _POSITIVE])
    m = magnetic
    # each magnetic atom a disc of its colour (what shows of a spin along the normal),
    # its in-plane part an arrow centred on it
    ax.scatter(x[m], y[m], s=12, c=value[m], cmap=cmap, vmin=-1.0, vmax=1.0, linewidths=0)
    arrows = ax.quiver(x[m], y[m], arrow_length * (spins[m] @ e1), arrow_length * (spins[m] @ e2),
                       value[m], cmap=cmap, clim=(-1.0, 1.0), angles="xy", scale_units="xy",
                       scale=1.0, pivot="middle", edgecolor="0.25", linewidth=0.3)
    if np.any(~m):
        ax.scatter(x[~m], y[~m], s=8, color=NONMAGNETIC)
    ax.set_aspect("equal")
    pad = 0.6 * arrow_length
    if len(pos):
        ax.set_xlim(x.min() - pad, x.max() + pad)
        ax.set_ylim(y.min() - pad, y.max() + pad)
    # e1 is the first in-plane cell vector, e2 = n × e1 (in the plane, across it)
    ax.set_xlabel(f"{_axis_name(e1, 'along the cell vector')} (Å)")
    ax.set_ylabel(f"{_axis_name(e2, 'across it, in the plane')} (Å)")
    along = _axis_name(normal, None)
    seen = ("along the film normal" if along is None else
            f"from {'+' if len(along) == 1 else ''}{along}")
    ax.set_title(f"spins seen {seen}, colour: {label}")
    fig.colorbar(arrows, ax=ax, label=label, shrink=0.8)


def _figure_class():
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise ImportError("pictures need matplotlib: pip install 'ase-spin[plot]' "
                          "(or pip install matplotlib)") from None
    return Figure
