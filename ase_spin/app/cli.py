"""The ``ase-spin`` command: run a scene from an input file, plot its log.

    ase-spin run INPUT.toml [--steps N] [--overwrite] [--no-progress]
    ase-spin plot LOG [-o PNG]
    ase-spin compile [INPUT.toml ...] [--jobs N]

The input file (TOML) is kept with the data; every relative path in it is
relative to its own folder. Its tables (docs/command_line.md has a full
example)::

    [structure]     file = "POSCAR" (anything ase.io.read reads; index, format)
                    or build = {function = "bulk", name = "Co", ...} (ase.build)
                    repeat = [5, 5, 5], rattle = 0.03 (Å), seed = 0
    [spins]         magnitude = 1.72 or {Co = 1.72, O = 0} (μB), direction =
                    [0, 0, 1] or "random", cone = 30 (degrees), seed = 0
    [velocities]    temperature = 100 (K), seed = 0
    [[terms]]       type = "LennardJones", epsilon = 0.4, ... (one table per term)
    [calculator]    skin = 0.3 (Å)
    [integrator]    type = "CollectivePRK", timestep = 0.1 (fs), steps = 1000,
                    order = 2, ... (any other keyword of the integrator)
    [output]        trajectory = "md.traj", log = "md.log", xyz = "spins.xyz",
                    interval = 10, overwrite = false

How the tables become objects: :mod:`ase_spin.app.inputs`.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from ..io.viewing import write_ovito_xyz
from ..md import IntegrationError
from .inputs import (InputError, build_integrator, build_scene, in_folder, load_input,
                     refuse_unknown, take)
from .warmup import compile_kernels

__all__ = ["main", "load_input", "build_scene", "plot_log", "InputError"]

# -- run ---------------------------------------------------------------------------

def _outputs(spec, stem, steps, overwrite):
    t = dict(spec.get("output", {}))
    paths = {}
    for key, default in (("trajectory", f"{stem}.traj"), ("log", f"{stem}.log"),
                         ("xyz", False)):
        value = take(t, "output", key, default, (str, bool))
        if value is True:
            value = f"{stem}.{'traj' if key == 'trajectory' else key}"
        paths[key] = value or None
    interval = take(t, "output", "interval", max(1, steps // 100), int)
    if interval < 1:
        raise InputError(f"[output] interval must be >= 1, got {interval}")
    overwrite = take(t, "output", "overwrite", False, bool) or overwrite
    refuse_unknown(t, "output")
    existing = [p for p in paths.values() if p and Path(p).exists()]
    if existing and not overwrite:
        raise InputError(f"output file(s) {', '.join(existing)} exist: remove them, name "
                         "others in [output], or run with --overwrite")
    for p in existing:
        os.remove(p)
    return paths, interval


def run(input_path, steps=None, overwrite=False, progress=True, out=None):
    """``ase-spin run``: build the scene of ``input_path``, integrate, write the
    outputs. Returns the integrator (closed)."""
    out = out or sys.stdout
    input_path = Path(input_path).resolve()
    spec = load_input(input_path)
    with in_folder(input_path.parent):
        atoms = build_scene(spec)
        nsteps = spec.get("integrator", {}).get("steps", 0) if steps is None else steps
        nsteps = nsteps if isinstance(nsteps, int) and not isinstance(nsteps, bool) else 0
        # the integrator's keywords checked before any output file is touched
        build_integrator(atoms, spec, dict.fromkeys(("trajectory", "log")), 1, steps)
        paths, interval = _outputs(spec, input_path.stem, nsteps, overwrite)
        dyn, nsteps = build_integrator(atoms, spec, paths, interval, steps)
        if paths["xyz"]:
            xyz = paths["xyz"]
            dyn.attach(lambda: write_ovito_xyz(xyz, atoms, append=True), interval=interval)
        terms = ", ".join(type(t).__name__ for t in atoms.calc.hamiltonian.terms)
        written = ", ".join(f"{k} {v}" for k, v in paths.items() if v) or "nothing"
        print(f"{len(atoms)} atoms ({atoms.get_chemical_formula()}), terms: {terms}\n"
              f"{type(dyn).__name__}, {dyn.dt / _fs():.4g} fs x {nsteps} steps "
              f"({nsteps * dyn.dt / _fs() / 1000:.4g} ps); writing {written} every "
              f"{interval} steps", file=out, flush=True)
        t0 = time.perf_counter()
        try:
            dyn.run(nsteps, progress=progress)
        finally:
            dyn.close()
        elapsed = time.perf_counter() - t0
        rate = nsteps / elapsed if elapsed > 0 else float("inf")
        print(f"done: {nsteps} steps in {elapsed:.1f} s ({rate:.3g} steps/s, "
              f"{1e6 * elapsed / max(nsteps * len(atoms), 1):.3g} µs per atom-step)",
              file=out, flush=True)
    return dyn


def _fs():
    from ase import units

    return units.fs


# -- plot ----------------------------------------------------------------------------

def read_log(path):
    """The columns of an integrator's log (SpinMDLogger, or ASE's MDLogger) as
    {header name: array}; repeated headers (runs appended to one log) skipped."""
    header = None
    rows = []
    with open(path) as fd:
        for line in fd:
            parts = line.split()
            if not parts:
                continue
            try:
                values = [float(x) for x in parts]
            except ValueError:
                if header is None:
                    header = parts
                continue
            if header is not None and len(values) == len(header):
                rows.append(values)
    if header is None or not rows:
        raise InputError(f"{str(path)!r} has no log lines (a header line, then rows of "
                         "numbers, as ase_spin's integrators write with logfile=...)")
    data = np.array(rows)
    return {name: data[:, k] for k, name in enumerate(header)}


def plot_log(path, output=None):
    """``ase-spin plot``: energies, temperatures and |M| against time from a log,
    as a PNG (default: the log's name with .png). Returns the PNG's path."""
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise InputError("ase-spin plot needs matplotlib: pip install 'ase-spin[plot]' "
                         "(or pip install matplotlib)") from None
    path = Path(path)
    if not path.is_file():
        raise InputError(f"log file {str(path)!r} not found")
    columns = read_log(path)
    if "Time[ps]" not in columns:
        raise InputError(f"{str(path)!r} has no Time[ps] column: not an MD log")
    t = columns["Time[ps]"]
    panels = [("energy − its first value (eV)",
               [c for c in ("Etot[eV]", "Epot[eV]", "Ekin[eV]", "Emag[eV]") if c in columns],
               True),
              ("temperature (K)", [c for c in ("T[K]", "Ts[K]") if c in columns], False),
              ("|M| (mean unit spin)", [c for c in ("|M|",) if c in columns], False)]
    panels = [p for p in panels if p[1]]
    fig = Figure(figsize=(7, 2.4 * len(panels)))
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (label, names, relative) in zip(axes, panels):
        for name in names:
            y = columns[name]
            if relative:
                ax.plot(t, y - y[0], label=f"{name[:-4]} ({y[0]:.6g} eV at start)")
            else:
                ax.plot(t, y, label=name)
        ax.set_ylabel(label)
        ax.legend(fontsize="small", loc="best")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (ps)")
    fig.suptitle(path.name)
    fig.tight_layout()
    output = Path(output) if output is not None else path.with_suffix(".png")
    fig.savefig(output, dpi=100)
    return output


# -- entry point ---------------------------------------------------------------------

def _parser():
    parser = argparse.ArgumentParser(
        prog="ase-spin", description="Spin-lattice dynamics with ase_spin.")
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run the scene of a TOML input file")
    r.add_argument("input", help="input file (TOML; see docs/command_line.md)")
    r.add_argument("--steps", type=int, help="number of steps (overrides the input)")
    r.add_argument("--overwrite", action="store_true",
                   help="replace existing output files")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    p = sub.add_parser("plot", help="plot energies, temperatures and |M| of a log")
    p.add_argument("log", help="log file written by an ase_spin integrator")
    p.add_argument("-o", "--output", help="PNG to write (default: LOG with .png)")
    c = sub.add_parser("compile", help="compile the numba kernels ahead of time (into "
                       "numba's disk cache) for the scenes of input files, or a built-in set")
    c.add_argument("inputs", nargs="*", help="input files (TOML) whose scenes to compile for")
    c.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                   help="processes compiling at once (default: the number of CPUs)")
    return parser


def main(argv=None):
    """The ``ase-spin`` console script. Returns the exit status: 0, or 2 for a
    problem with the input (the message on stderr)."""
    args = _parser().parse_args(argv)
    try:
        if args.command == "run":
            run(args.input, steps=args.steps, overwrite=args.overwrite,
                progress=not args.no_progress)
        elif args.command == "compile":
            if args.jobs < 1:
                raise InputError(f"--jobs must be at least 1, got {args.jobs}")
            os.environ.setdefault("ASE_SPIN_QUIET_COMPILE", "1")  # it says what it does
            compile_kernels(args.inputs, jobs=args.jobs)
        else:
            png = plot_log(args.log, args.output)
            print(f"wrote {png}")
    except (InputError, FileExistsError) as err:
        print(f"ase-spin: error: {err}", file=sys.stderr)
        return 2
    except IntegrationError as err:
        print(f"ase-spin: the run stopped: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("ase-spin: interrupted; the outputs hold the steps completed", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
