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

``spin_angle`` and ``spin_z`` are scalars, so ``ase gui`` lists them under
View → Colors ("By user-defined ...") too. See docs/viewing.md.
"""

from __future__ import annotations

import os

import numpy as np

from ..spins import get_moments, split_moments

__all__ = ["spin_colors", "spin_angles", "magnetization", "write_ovito_xyz",
           "ovito_pipeline", "plot_spins"]

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
    if not isinstance(by, str) or by not in _COLOR_BY:
        raise ValueError(f"colour by must be one of {_COLOR_BY}, got {by!r}")
    spins = _spins_of(atoms_or_spins)
    if by == "angle":
        v = np.cos(np.radians(np.nan_to_num(spin_angles(spins))))
    else:
        v = spins[:, "xyz".index(by)]
    v = np.clip(v, -1.0, 1.0)[:, None]
    rgb = np.where(v >= 0.0, _ZERO + v * (_POSITIVE - _ZERO), _ZERO - v * (_NEGATIVE - _ZERO))
    rgb[~np.any(spins != 0.0, axis=1)] = NONMAGNETIC
    return rgb


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
    ``spin_z``), the magnetisation M and |M| in its comment line, and the
    energy, forces and stress if the frame's calculator holds them for this
    state. The frames given are not changed. Returns the number of frames
    written.
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


def plot_spins(atoms, path=None, color_by="angle", ax=None, arrow_length=1.2):
    """A matplotlib 3D picture of the spins: an arrow s_i at each magnetic atom,
    coloured as :func:`spin_colors`, non-magnetic atoms as grey points. Draws
    into ``ax`` (a 3D axes) or a new figure; saves to ``path`` if given.
    Returns the figure. Needs matplotlib (``pip install 'ase-spin[plot]'``)."""
    Figure = _figure_class()
    spins, _ = split_moments(get_moments(atoms))
    rgb = spin_colors(spins, color_by)
    magnetic = np.any(spins != 0.0, axis=1)
    if ax is None:
        fig = Figure(figsize=(6, 5))
        ax = fig.add_subplot(projection="3d")
    else:
        fig = ax.figure
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
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def _figure_class():
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise ImportError("pictures need matplotlib: pip install 'ase-spin[plot]' "
                          "(or pip install matplotlib)") from None
    return Figure
