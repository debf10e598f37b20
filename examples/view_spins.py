"""Pictures of spins for docs/viewing.md: a spin spiral in fcc Co after 0.1 ps
of spin–lattice dynamics, written as OVITO-ready extended XYZ and drawn twice —
by OVITO's Python module (if installed; headless rendering needs a Vulkan
driver, e.g. Debian's libvulkan1 + mesa-vulkan-drivers) and by matplotlib.

    python examples/view_spins.py [--out DIR] [--steps 200] [--no-xyz]

writes, in DIR (default: the current folder), spiral.xyz (every 50th step, open it
with OVITO or `ase gui spiral.xyz`), spiral_matplotlib.png and, with OVITO,
spiral_ovito.png. The docs' pictures are made with
`python examples/view_spins.py --out docs/figures/viewing --no-xyz`.
"""

import argparse
import tempfile
from pathlib import Path

import numpy as np
from ase import units
from ase.build import bulk
from ase.io import Trajectory

import ase_spin
from ase_spin import (BetheSlater, CollectivePRK, Exchange, LennardJones,
                      SpinLatticeCalculator, UniaxialAnisotropy)

parser = argparse.ArgumentParser(
    description="A spin spiral in fcc Co after 0.1 ps of spin–lattice dynamics, written as "
    "OVITO-ready extended XYZ and drawn by OVITO (if installed) and matplotlib.")
parser.add_argument("--out", default=".", type=Path,
                    help="folder for the pictures and spiral.xyz (default: the current folder)")
parser.add_argument("--steps", type=int, default=200, help="steps of 0.5 fs (default 200)")
parser.add_argument("--no-xyz", action="store_true",
                    help="do not keep spiral.xyz (it is large): only the pictures")
args = parser.parse_args()
if args.out.suffix.lower() == ".png":
    parser.error("--out is a folder: this example writes two pictures and spiral.xyz")
out = args.out
out.mkdir(parents=True, exist_ok=True)

atoms = bulk("Co", "fcc", a=3.54, cubic=True).repeat((8, 4, 2))  # 256 atoms
# a spiral: the spin turns once about y along x, plus 10° of noise
rng = np.random.default_rng(0)
phase = 2 * np.pi * atoms.positions[:, 0] / atoms.cell[0, 0]
spins = np.column_stack([np.sin(phase), np.zeros(len(atoms)), np.cos(phase)])
spins += 0.17 * rng.normal(size=spins.shape)
ase_spin.set_spins(atoms, spins, magnitudes=1.72)
p = rng.normal(size=(len(atoms), 3)) * np.sqrt(atoms.get_masses()[:, None] * units.kB * 100)
atoms.set_momenta(p - p.mean(axis=0))
atoms.calc = SpinLatticeCalculator([
    LennardJones(epsilon=0.4, sigma=2.2742, rc=4.7, cutoff="shift"),
    Exchange(BetheSlater(J1=0.0446928, J2=0.003496, J3=1.4885), rc=4.0),
    UniaxialAnisotropy(K=0.001, axis=[0, 0, 1]),
])

with tempfile.TemporaryDirectory() as scratch:
    # the run's trajectory is only a step towards the pictures: kept out of the way
    traj_path = Path(scratch) / "spiral.traj"
    with Trajectory(traj_path, "w", atoms) as traj:
        dyn = CollectivePRK(atoms, timestep=0.5 * units.fs, trajectory=traj, loginterval=50)
        dyn.run(args.steps, progress=True)
    xyz = (Path(scratch) if args.no_xyz else out) / "spiral.xyz"
    n = ase_spin.write_ovito_xyz(xyz, traj_path, color_by="z")  # every frame of the run
    if not args.no_xyz:
        print(f"wrote {xyz} ({n} frames)")

    ase_spin.plot_spins(atoms, out / "spiral_matplotlib.png", color_by="z")
    print(f"wrote {out / 'spiral_matplotlib.png'}")

    try:
        from ovito.vis import TachyonRenderer, Viewport
    except ImportError:
        print("OVITO not installed (pip install ovito): no OVITO picture")
    else:
        from ase_spin.io.viewing import ovito_pipeline

        pipeline = ovito_pipeline(xyz)
        pipeline.add_to_scene()
        vp = Viewport(type=Viewport.Type.Perspective, camera_dir=(-0.35, 1.0, -0.45))
        vp.zoom_all()
        try:
            vp.render_image(filename=str(out / "spiral_ovito.png"), size=(800, 500),
                            frame=n - 1, renderer=TachyonRenderer())
        except RuntimeError as err:  # e.g. no Vulkan driver
            print(f"OVITO cannot render here: {err}")
        else:
            print(f"wrote {out / 'spiral_ovito.png'}")
        finally:
            pipeline.remove_from_scene()
