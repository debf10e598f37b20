"""Viewing spins: the OVITO-ready extxyz export, colours, ase gui's reading of
(N, 3) moments, and rendered pictures (OVITO when installed, matplotlib)."""

import numpy as np
import pytest
from ase.build import bulk
from ase.calculators.singlepoint import SinglePointCalculator
from ase.io import Trajectory, read

import ase_spin
from ase_spin.io import viewing
from ase_spin.io.viewing import spin_colors, write_ovito_xyz


def scene(n=2, seed=0):
    atoms = bulk("Fe", "bcc", a=2.87, cubic=True).repeat(n)
    del atoms.arrays["initial_magmoms"]
    rng = np.random.default_rng(seed)
    ase_spin.set_spins(atoms, rng.normal(size=(len(atoms), 3)) + [0, 0, 1.5],
                       magnitudes=rng.uniform(1.5, 2.5, len(atoms)))
    return atoms


def test_extxyz_reads_back_with_the_spin_columns(tmp_path):
    atoms = scene()
    atoms.arrays["initial_magmoms"][3] = 0.0  # one non-magnetic atom
    before = {k: v.copy() for k, v in atoms.arrays.items()}
    assert write_ovito_xyz(tmp_path / "s.xyz", [atoms, atoms]) == 2
    assert set(atoms.arrays) == set(before)  # the frames given are not changed
    for k, v in before.items():
        np.testing.assert_array_equal(atoms.arrays[k], v)
    back = read(tmp_path / "s.xyz", ":")
    assert len(back) == 2
    b = back[0]
    spins, mu = ase_spin.spins.split_moments(atoms.arrays["initial_magmoms"])
    np.testing.assert_allclose(b.arrays["dipoles"], spins, atol=1e-7)
    np.testing.assert_allclose(b.arrays["dipoles_mag"], mu, atol=1e-7)
    np.testing.assert_allclose(b.arrays["initial_magmoms"], atoms.arrays["initial_magmoms"],
                               atol=1e-7)
    np.testing.assert_allclose(b.arrays["spin_z"], spins[:, 2], atol=1e-7)
    M = spins[mu > 0].mean(axis=0)
    np.testing.assert_allclose(b.info["magnetization"], M, atol=1e-7)
    cos = spins @ M / np.linalg.norm(M)
    magnetic = mu > 0
    np.testing.assert_allclose(np.cos(np.radians(b.arrays["spin_angle"][magnetic])),
                               cos[magnetic], atol=1e-6)
    np.testing.assert_allclose(b.arrays["color"], spin_colors(atoms), atol=1e-7)
    np.testing.assert_allclose(b.arrays["vector_color"], b.arrays["color"])
    np.testing.assert_allclose(b.arrays["color"][3], viewing.NONMAGNETIC, atol=1e-7)


def test_colour_scale_ends_and_middle():
    """+1 red, −1 blue, 0 light grey, linear between; by angle to M or by component."""
    s = np.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0, 0, 0], [0, 0.6, 0.8]])
    by_z = spin_colors(s, "z")
    np.testing.assert_allclose(by_z[0], viewing._POSITIVE)
    np.testing.assert_allclose(by_z[1], viewing._NEGATIVE)
    np.testing.assert_allclose(by_z[2], viewing._ZERO)
    np.testing.assert_allclose(by_z[3], viewing.NONMAGNETIC)
    np.testing.assert_allclose(by_z[4], viewing._ZERO + 0.8 * (viewing._POSITIVE - viewing._ZERO))
    np.testing.assert_allclose(spin_colors(s, "y")[4],
                               viewing._ZERO + 0.6 * (viewing._POSITIVE - viewing._ZERO))
    # by angle: M of these four spins points along (1, 0.6, 0.8)/4 ...
    M = s[[0, 1, 2, 4]].mean(axis=0)
    c = s @ M / np.linalg.norm(M)
    want = np.where(c[:, None] >= 0, viewing._ZERO + c[:, None] * (viewing._POSITIVE - viewing._ZERO),
                    viewing._ZERO - c[:, None] * (viewing._NEGATIVE - viewing._ZERO))
    got = spin_colors(s, "angle")
    np.testing.assert_allclose(got[[0, 1, 2, 4]], want[[0, 1, 2, 4]], atol=1e-12)
    # ... a ferromagnet is red all over, its reversed spin blue
    fm = np.tile([0.0, 1.0, 0.0], (5, 1))
    fm[2] = [0, -1, 0]
    got = spin_colors(fm, "angle")
    np.testing.assert_allclose(got[[0, 1, 3, 4]], np.tile(viewing._POSITIVE, (4, 1)))
    np.testing.assert_allclose(got[2], viewing._NEGATIVE)
    with pytest.raises(ValueError, match="colour by must be one of"):
        spin_colors(s, "w")


def test_frames_from_a_trajectory_file_with_their_energies(tmp_path):
    atoms = scene()
    with Trajectory(tmp_path / "t.traj", "w") as traj:
        for k in range(3):
            frame = atoms.copy()
            frame.positions[0, 0] += 0.01 * k
            frame.calc = SinglePointCalculator(frame, energy=-1.5 - k,
                                               forces=np.full((len(frame), 3), 0.1 * k))
            traj.write(frame)
    assert write_ovito_xyz(tmp_path / "t.xyz", tmp_path / "t.traj", color_by="x") == 3
    back = read(tmp_path / "t.xyz", ":")
    assert [b.get_potential_energy() for b in back] == [-1.5, -2.5, -3.5]
    np.testing.assert_allclose(back[2].get_forces(), 0.2)
    np.testing.assert_allclose(back[1].arrays["color"], spin_colors(atoms, "x"), atol=1e-7)
    # appended frame by frame, as the command line does
    write_ovito_xyz(tmp_path / "t.xyz", atoms, append=True)
    assert len(read(tmp_path / "t.xyz", ":")) == 4


def test_stale_calculator_results_are_not_written(tmp_path):
    atoms = scene()
    atoms.calc = SinglePointCalculator(atoms, energy=1.0)
    atoms.positions[0] += 0.1  # results now belong to another state
    write_ovito_xyz(tmp_path / "s.xyz", atoms)
    assert read(tmp_path / "s.xyz").calc is None


def test_bad_frames_are_refused(tmp_path):
    atoms = bulk("Fe", "bcc", a=2.87, cubic=True).repeat(2)  # collinear (N,) moments
    with pytest.raises(ValueError, match="frame 1: .*collinear"):
        write_ovito_xyz(tmp_path / "s.xyz", [scene(), atoms])
    del atoms.arrays["initial_magmoms"]
    with pytest.raises(ValueError, match="frame 0: the atoms carry no"):
        write_ovito_xyz(tmp_path / "s.xyz", atoms)
    with pytest.raises(TypeError, match="frame 1 is not an ase.Atoms"):
        write_ovito_xyz(tmp_path / "s.xyz", [scene(), "x"])
    with pytest.raises(ValueError, match="colour by"):
        write_ovito_xyz(tmp_path / "s.xyz", scene(), color_by="angles")
    with pytest.raises(ValueError, match="no frames"):
        write_ovito_xyz(tmp_path / "s.xyz", [])
    assert not (tmp_path / "s.xyz").exists()


def test_ase_gui_reads_the_vector_moments(tmp_path):
    """What View → Show magmoms draws: ase.gui's get_magmoms gives the (N, 3)
    moments of a trajectory frame and of the extxyz export; the export's
    scalar columns are what View → Colors can colour by."""
    pytest.importorskip("ase.gui.utils")
    from ase.gui.utils import get_magmoms

    atoms = scene()
    with Trajectory(tmp_path / "t.traj", "w") as traj:
        traj.write(atoms)
    write_ovito_xyz(tmp_path / "s.xyz", atoms)
    for path in ("t.traj", "s.xyz"):
        frame = read(tmp_path / path)
        np.testing.assert_allclose(get_magmoms(frame), atoms.arrays["initial_magmoms"],
                                   atol=1e-7)
    frame = read(tmp_path / "s.xyz")
    # View → Colors → By user-defined "spin_angle": ase gui's own colouring code
    from ase.gui.view import View

    class Gui:  # the attributes of ase.gui's View that its colouring reads
        def get_color_scalars(self, frame=None):
            return View.get_color_scalars(self, frame)

    gui = Gui()
    gui.atoms = frame
    gui.colormode_data = ([f"#{k:02x}0000" for k in range(0, 250, 10)], 0.0, 180.0)
    for column in ("spin_angle", "spin_z"):
        assert frame.arrays[column].shape == (len(atoms),)
        gui.colormode = column
        colours = View.get_colors(gui)
        assert len(colours) == len(atoms)
    gui.colormode = "spin_angle"
    order = np.argsort(frame.arrays["spin_angle"])
    shades = [int(View.get_colors(gui)[i][1:3], 16) for i in order]
    assert shades == sorted(shades) and shades[-1] > shades[0]


def test_matplotlib_picture(tmp_path):
    pytest.importorskip("matplotlib")
    from matplotlib.image import imread

    atoms = scene(3)
    atoms.arrays["initial_magmoms"][:4] = 0.0
    fig = ase_spin.plot_spins(atoms, tmp_path / "spins.png", color_by="z")
    ax = fig.axes[0]
    quiver = ax.collections[0]
    # one shaft and two head lines per magnetic atom
    assert len(quiver.get_segments()) == 3 * (len(atoms) - 4)
    image = imread(tmp_path / "spins.png")[..., :3]
    red = (image[..., 0] > 0.55) & (image[..., 1] < 0.25) & (image[..., 2] < 0.3)
    assert red.sum() > 50  # arrows in the colour of s_z ≈ +1


def test_ovito_reads_the_columns_and_renders_arrows(tmp_path):
    """OVITO maps dipoles → Dipole Orientation, dipoles_mag → Dipole Magnitude,
    color → Color, vector_color → Vector Color; the pipeline helper switches the
    arrows on. Rendered headless when OVITO and a Vulkan driver are present."""
    pytest.importorskip("ovito")
    pytest.importorskip("matplotlib")
    atoms = scene(3)
    write_ovito_xyz(tmp_path / "s.xyz", atoms, color_by="z")
    pipeline = viewing.ovito_pipeline(tmp_path / "s.xyz")
    data = pipeline.compute()
    p = data.particles
    spins, mu = ase_spin.spins.split_moments(atoms.arrays["initial_magmoms"])
    np.testing.assert_allclose(np.asarray(p["Dipole Orientation"]), spins, atol=1e-7)
    np.testing.assert_allclose(np.asarray(p["Dipole Magnitude"]), mu, atol=1e-7)
    np.testing.assert_allclose(np.asarray(p["Color"]), spin_colors(atoms, "z"), atol=1e-6)
    np.testing.assert_allclose(np.asarray(p["Vector Color"]), spin_colors(atoms, "z"),
                               atol=1e-6)
    assert p["Dipole Orientation"].vis.enabled
    M = spins.mean(axis=0)
    np.testing.assert_allclose(data.attributes["magnetization"], M, atol=1e-7)
    np.testing.assert_allclose(data.attributes["abs_magnetization"], np.linalg.norm(M),
                               atol=1e-7)
    from ovito.vis import TachyonRenderer, Viewport

    pipeline.add_to_scene()
    try:
        vp = Viewport(type=Viewport.Type.Perspective, camera_dir=(-1, -0.6, -0.5))
        vp.zoom_all()
        vp.render_image(filename=str(tmp_path / "ovito.png"), size=(320, 240),
                        renderer=TachyonRenderer())
    except RuntimeError as err:  # no Vulkan driver on this machine
        pytest.skip(f"OVITO cannot render here: {err}")
    finally:
        pipeline.remove_from_scene()
    from matplotlib.image import imread

    image = imread(tmp_path / "ovito.png")[..., :3]
    assert image.std() > 0.05
    reddish = (image[..., 0] > image[..., 2] + 0.2).sum()
    assert reddish > 100  # spins mostly +z: red atoms and arrows


def test_ovito_pipeline_needs_ovito(monkeypatch, tmp_path):
    import sys

    monkeypatch.setitem(sys.modules, "ovito.io", None)
    with pytest.raises(ImportError, match="pip install ovito"):
        viewing.ovito_pipeline(tmp_path / "x.xyz")


def _film(n=6, a=2.5, rattle=0.0, normal_axis=2):
    """A square monolayer, periodic in-plane, spins mostly along +normal with a
    ring tilted into the plane and the middle reversed."""
    from ase import Atoms

    ij = np.array([(i, j) for j in range(n) for i in range(n)], dtype=float) * a
    pos = np.column_stack([ij, np.zeros(n * n)])
    cell = np.diag([n * a, n * a, 10.0])
    pbc = [True, True, False]
    perm = {2: [0, 1, 2], 0: [2, 0, 1]}[normal_axis]  # the normal along z or along x
    atoms = Atoms(f"Fe{n * n}", positions=pos[:, perm], cell=cell[perm][:, perm],
                  pbc=[pbc[k] for k in perm])
    atoms.rattle(rattle, seed=1)
    d = ij - ij.mean(axis=0)
    rho = np.linalg.norm(d, axis=1)
    theta = np.pi * np.clip(1.0 - rho / (0.6 * n * a), 0.0, 1.0)
    radial = d / np.where(rho > 0, rho, 1.0)[:, None]
    s = np.column_stack([np.sin(theta)[:, None] * radial, np.cos(theta)])
    ase_spin.set_spins(atoms, s[:, perm], magnitudes=2.0)
    return atoms


def test_film_plane_finds_the_normal_of_flat_systems():
    atoms = _film(rattle=0.1)
    n, e1, e2, flat = viewing.film_plane(atoms)
    np.testing.assert_allclose(n, [0, 0, 1])
    np.testing.assert_allclose(e1, [1, 0, 0])
    np.testing.assert_allclose(e2, [0, 1, 0])
    assert flat
    side = _film(normal_axis=0)  # a film in the yz plane, non-periodic along x
    n, e1, e2, flat = viewing.film_plane(side)
    np.testing.assert_allclose(n, [1, 0, 0])
    np.testing.assert_allclose(np.cross(e1, e2), n)
    assert flat
    assert not viewing.film_plane(scene(3))[3]  # bulk
    slab = bulk("Fe", "bcc", a=2.87, cubic=True).repeat((8, 8, 3))
    slab.pbc = [True, True, False]
    assert not viewing.film_plane(slab)[3]  # 5.7 Å thick, 20 Å wide: not a film
    two = bulk("Fe", "bcc", a=2.87, cubic=True).repeat((10, 10, 1))
    two.pbc = [True, True, False]
    assert viewing.film_plane(two)[3]  # two layers 1.4 Å apart


def test_matplotlib_picture_of_a_film_is_a_top_view(tmp_path):
    """A film is drawn from above: a 2D quiver of the in-plane spins coloured
    by s_z, equal aspect, in Å; view="3d" still gives the 3D picture."""
    pytest.importorskip("matplotlib")
    from matplotlib.image import imread
    from matplotlib.quiver import Quiver

    atoms = _film(rattle=0.05)
    atoms.arrays["initial_magmoms"][0] = 0.0  # a non-magnetic corner atom
    fig = ase_spin.plot_spins(atoms, tmp_path / "film.png")
    ax = fig.axes[0]
    assert ax.name == "rectilinear" and ax.get_aspect() == 1.0
    assert ax.get_xlabel() == "x (Å)" and ax.get_ylabel() == "y (Å)"
    (quiver,) = [c for c in ax.collections if isinstance(c, Quiver)]
    spins = ase_spin.get_spins(atoms)[1:]
    assert quiver.N == len(atoms) - 1
    np.testing.assert_allclose(quiver.get_array(), spins[:, 2])  # coloured by s_z
    np.testing.assert_allclose(np.column_stack([quiver.U, quiver.V]) / np.hypot(
        quiver.U, quiver.V).max(), spins[:, :2] / np.hypot(*spins[:, :2].T).max(), atol=1e-12)
    assert "s_z" in fig.axes[1].get_ylabel()  # the colour bar
    image = imread(tmp_path / "film.png")[..., :3]
    red = (image[..., 0] > 0.55) & (image[..., 1] < 0.25) & (image[..., 2] < 0.3)
    blue = (image[..., 2] > 0.55) & (image[..., 0] < 0.35)
    assert red.sum() > 50 and blue.sum() > 20  # s_z = +1 at the rim, −1 in the middle
    fig = ase_spin.plot_spins(atoms, view="3d")
    assert fig.axes[0].name == "3d"
    fig = ase_spin.plot_spins(scene(2), view="top", color_by="x")
    assert fig.axes[0].name == "rectilinear"
    with pytest.raises(ValueError, match="view"):
        ase_spin.plot_spins(atoms, view="side")
    with pytest.raises(ValueError, match="needs a 2D axes"):
        ase_spin.plot_spins(atoms, view="top", ax=fig.add_subplot(projection="3d"))


def test_ase_gui_tilted_view_shows_moments_along_a_film_normal():
    """docs/viewing.md: from ase gui's default view (down z) a moment along z
    projects to nothing; `ase gui -R -70x` shows it at 94 % of its length."""
    pytest.importorskip("ase.gui")
    from ase.utils import rotate

    up = np.array([0.0, 0.0, 1.0])
    assert np.linalg.norm((up @ rotate(""))[:2]) == 0.0
    assert np.linalg.norm((up @ rotate("-70x"))[:2]) > 0.93
