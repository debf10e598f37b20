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

Terms, couplings and integrators are looked up by name among the classes
``ase_spin`` exports: a term added to the package (and exported) is usable
here with no change to this file. A table with a ``type`` key anywhere inside
a term's parameters builds that object (``coupling = {type = "BetheSlater",
J1 = ...}``); every other key is a keyword argument, in the class's own units —
only the integrator's ``timestep`` is given in fs here.
"""

from __future__ import annotations

import argparse
import contextlib
import inspect
import os
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["main", "load_input", "build_scene", "plot_log", "InputError"]

_TABLES = ("structure", "spins", "velocities", "terms", "calculator", "integrator", "output")


class InputError(ValueError):
    """The input file is wrong; the message says where."""


# -- reading the input ----------------------------------------------------------

def _toml():
    try:
        import tomllib
    except ModuleNotFoundError:  # Python < 3.11
        import tomli as tomllib
    return tomllib


def load_input(path):
    """The input file as a dict, its tables checked against the known ones."""
    tomllib = _toml()
    path = Path(path)
    if not path.is_file():
        raise InputError(f"input file {str(path)!r} not found")
    with open(path, "rb") as fd:
        try:
            spec = tomllib.load(fd)
        except tomllib.TOMLDecodeError as err:
            raise InputError(f"{str(path)!r} is not valid TOML: {err}") from None
    unknown = sorted(set(spec) - set(_TABLES))
    if unknown:
        raise InputError(f"unknown table(s) {', '.join(unknown)} in {str(path)!r}; "
                         f"the tables are {', '.join(_TABLES)}")
    for name in _TABLES:
        want = list if name == "terms" else dict
        if name in spec and not isinstance(spec[name], want):
            form = "[[terms]] tables" if want is list else f"a [{name}] table"
            raise InputError(f"{name} must be {form}, got {spec[name]!r}")
    return spec


def _take(table, where, key, default=None, kind=None):
    """table.pop(key), checked to be of ``kind`` (a type or a tuple of types;
    a TOML true/false is not taken for a number)."""
    value = table.pop(key, default)
    if value is default or kind is None:
        return value
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
        names = " or ".join({"int": "an integer", "float": "a number", "str": "a string",
                             "list": "a list", "dict": "a table", "bool": "true/false"}
                            [k.__name__] for k in kinds)
        raise InputError(f"[{where}] {key} must be {names}, got {value!r}")
    return value


def _no_more(table, where):
    if table:
        raise InputError(f"[{where}] has unknown key(s) {', '.join(sorted(table))}")


# -- objects by name --------------------------------------------------------------

def _exported(base):
    """Classes ase_spin exports that derive from ``base``, by name (the
    abstract bases of terms excluded)."""
    import ase_spin
    import ase_spin.terms

    found = {}
    for module in (ase_spin, ase_spin.terms):
        for name, obj in vars(module).items():
            if (not name.startswith("_") and inspect.isclass(obj) and issubclass(obj, base)
                    and not inspect.isabstract(obj)):
                found.setdefault(name, obj)
    for abstract in ("Term", "SpinTerm", "SingleSiteTerm", "Coupling",
                     "SpinLatticeDynamics"):
        found.pop(abstract, None)
    return found


def make(spec, where, base=object):
    """Build ``spec["type"](**rest)``: a class exported by ase_spin, a subclass
    of ``base``; nested tables with a ``type`` key are built the same way."""
    spec = dict(spec)
    name = spec.pop("type", None)
    choices = _exported(base)
    if not isinstance(name, str):
        raise InputError(f"{where} needs type = one of {', '.join(sorted(choices))}")
    if name not in choices:
        raise InputError(f"{where}: unknown type {name!r}; choose one of "
                         f"{', '.join(sorted(choices))}")
    kwargs = {k: _value(v, f"{where}.{k}") for k, v in spec.items()}
    try:
        return choices[name](**kwargs)
    except TypeError as err:
        raise InputError(f"{where} ({name}): {err}") from None
    except ValueError as err:
        raise InputError(f"{where} ({name}): {err}") from None


def _value(v, where):
    if isinstance(v, dict):
        if "type" in v:
            return make(v, where)
        return {k: _value(x, f"{where}.{k}") for k, x in v.items()}
    if isinstance(v, list):
        return [_value(x, f"{where}[{k}]") for k, x in enumerate(v)]
    return v


# -- the scene ---------------------------------------------------------------------

def _structure(table):
    from ase import build
    from ase.io import read

    t = dict(table)
    if ("file" in t) == ("build" in t):
        raise InputError("[structure] needs either file = \"...\" (read with ase.io.read) "
                         "or build = {function = \"bulk\", ...} (ase.build)")
    if "file" in t:
        path = _take(t, "structure", "file", kind=str)
        index = _take(t, "structure", "index", -1, (int, str))
        fmt = _take(t, "structure", "format", None, str)
        if not Path(path).is_file():
            raise InputError(f"[structure] file {path!r} not found (relative paths are "
                             f"relative to the input file's folder)")
        atoms = read(path, index=index, format=fmt)
        if isinstance(atoms, list):
            raise InputError(f"[structure] index {index!r} selects {len(atoms)} frames; "
                             "give one frame")
    else:
        recipe = dict(_take(t, "structure", "build", kind=dict))
        function = recipe.pop("function", None)
        names = sorted(n for n in getattr(build, "__all__", dir(build))
                       if not n.startswith("_") and callable(getattr(build, n)))
        if function not in names:
            raise InputError(f"[structure] build.function must be a function of ase.build "
                             f"({', '.join(names)}); got {function!r}")
        try:
            atoms = getattr(build, function)(**recipe)
        except (TypeError, ValueError, KeyError, RuntimeError) as err:
            raise InputError(f"[structure] build = {function}(...): {err}") from None
    repeat = _take(t, "structure", "repeat", None, (int, list))
    if repeat is not None:
        atoms = atoms.repeat(repeat)
    rattle = _take(t, "structure", "rattle", 0.0, (int, float))
    seed = _take(t, "structure", "seed", 0, int)
    if rattle:
        atoms.rattle(float(rattle), seed=seed)
    _no_more(t, "structure")
    return atoms


def _spins(atoms, table):
    import ase_spin

    t = dict(table)
    rng = np.random.default_rng(_take(t, "spins", "seed", 0, int))
    n = len(atoms)
    magnitude = _take(t, "spins", "magnitude", None, (int, float, dict))
    if isinstance(magnitude, dict):
        symbols = atoms.get_chemical_symbols()
        missing = sorted(set(symbols) - set(magnitude))
        if missing:
            raise InputError(f"[spins] magnitude has no value for {', '.join(missing)} "
                             "(give 0 for a non-magnetic species)")
        magnitude = np.array([float(magnitude[s]) for s in symbols])
    direction = _take(t, "spins", "direction", None, (list, str))
    cone = _take(t, "spins", "cone", None, (int, float))
    _no_more(t, "spins")
    if direction is None:
        has = atoms.has("initial_magmoms") and np.ndim(atoms.arrays["initial_magmoms"]) == 2
        axis = ase_spin.get_spins(atoms) if has else np.array([0.0, 0.0, 1.0])
    elif direction == "random":
        v = rng.normal(size=(n, 3))
        axis = v / np.linalg.norm(v, axis=1)[:, None]
    elif isinstance(direction, str):
        raise InputError(f'[spins] direction must be three numbers or "random", got '
                         f"{direction!r}")
    else:
        axis = np.broadcast_to(np.asarray(direction, dtype=float), (n, 3))
    directions = axis
    if cone:
        directions = _in_cone(np.atleast_2d(axis), float(cone), rng)
    try:
        ase_spin.set_spins(atoms, directions, magnitudes=magnitude)
    except (TypeError, ValueError) as err:
        raise InputError(f"[spins]: {err}") from None


def _in_cone(axes, degrees, rng):
    """Directions uniform on the cap of half-angle ``degrees`` about each axis."""
    n = len(axes)
    cz = rng.uniform(np.cos(np.radians(degrees)), 1.0, n)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    sz = np.sqrt(1.0 - cz**2)
    local = np.column_stack([sz * np.cos(phi), sz * np.sin(phi), cz])
    out = np.zeros_like(local)
    for k, a in enumerate(axes):  # set-up only, once per run
        norm = np.linalg.norm(a)
        if norm == 0.0:
            continue
        z = a / norm
        helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = np.cross(helper, z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        out[k] = local[k] @ np.array([x, y, z])
    return out


def _velocities(atoms, table):
    from ase.md import velocitydistribution as vd

    t = dict(table)
    temperature = _take(t, "velocities", "temperature", None, (int, float))
    seed = _take(t, "velocities", "seed", 0, int)
    _no_more(t, "velocities")
    if temperature is None:
        raise InputError("[velocities] needs temperature = ... (K)")
    if temperature < 0:
        raise InputError(f"[velocities] temperature must be >= 0 K, got {temperature}")
    rng = np.random.default_rng(seed)
    if hasattr(vd, "thermalize_momenta"):  # ASE >= 3.29
        vd.thermalize_momenta(atoms, float(temperature), rng=rng)
    else:
        vd.MaxwellBoltzmannDistribution(atoms, temperature_K=float(temperature), rng=rng)
    vd.Stationary(atoms)


def build_scene(spec):
    """Atoms with spins, momenta and the calculator from an input dict (paths
    relative to the current folder)."""
    from .calculator import SpinLatticeCalculator
    from .terms import Term

    if "structure" not in spec:
        raise InputError("the input needs a [structure] table")
    atoms = _structure(spec["structure"])
    if "spins" in spec:
        _spins(atoms, spec["spins"])
    if "velocities" in spec:
        _velocities(atoms, spec["velocities"])
    terms = spec.get("terms")
    if not terms:
        raise InputError("the input needs at least one [[terms]] table")
    built = []
    for k, term in enumerate(terms):
        if not isinstance(term, dict):
            raise InputError(f"[[terms]] #{k + 1} must be a table, got {term!r}")
        built.append(make(term, f"[[terms]] #{k + 1}", Term))
    calc = dict(spec.get("calculator", {}))
    skin = _take(calc, "calculator", "skin", 0.3, (int, float))
    _no_more(calc, "calculator")
    atoms.calc = SpinLatticeCalculator(built, skin=skin)
    spin_terms = [t for t in built if t.spin_dependent]
    moments = atoms.arrays.get("initial_magmoms")
    if moments is not None and np.ndim(moments) == 1 and np.any(moments):
        raise InputError("the structure carries collinear moments (one number per atom): add "
                         "a [spins] table with a direction (its magnitudes are kept unless "
                         "magnitude = ... is given)")
    if spin_terms and (moments is None or not np.any(moments)):
        raise InputError(f"the terms {', '.join(type(t).__name__ for t in spin_terms)} act "
                         "on spins, but the structure has no magnetic moments: add a "
                         "[spins] table (magnitude = ... μB)")
    return atoms


# -- run ---------------------------------------------------------------------------

def _outputs(spec, stem, steps, overwrite):
    t = dict(spec.get("output", {}))
    paths = {}
    for key, default in (("trajectory", f"{stem}.traj"), ("log", f"{stem}.log"),
                         ("xyz", False)):
        value = _take(t, "output", key, default, (str, bool))
        if value is True:
            value = f"{stem}.{'traj' if key == 'trajectory' else key}"
        paths[key] = value or None
    interval = _take(t, "output", "interval", max(1, steps // 100), int)
    if interval < 1:
        raise InputError(f"[output] interval must be >= 1, got {interval}")
    overwrite = _take(t, "output", "overwrite", False, bool) or overwrite
    _no_more(t, "output")
    existing = [p for p in paths.values() if p and Path(p).exists()]
    if existing and not overwrite:
        raise InputError(f"output file(s) {', '.join(existing)} exist: remove them, name "
                         "others in [output], or run with --overwrite")
    for p in existing:
        os.remove(p)
    return paths, interval


def _integrator(atoms, spec, paths, interval, steps_override):
    from ase import units

    from .md import SpinLatticeDynamics

    t = dict(spec.get("integrator", {}))
    t.setdefault("type", "CollectivePRK")
    steps = _take(t, "integrator", "steps", None, int)
    if steps_override is not None:
        steps = steps_override
    if steps is None or steps < 0:
        raise InputError(f"[integrator] needs steps = a number >= 0, got {steps!r}")
    timestep = _take(t, "integrator", "timestep", None, (int, float))
    if timestep is None or not timestep > 0:
        raise InputError(f"[integrator] needs timestep = ... (fs, > 0), got {timestep!r}")
    t["timestep"] = float(timestep) * units.fs
    t["atoms"] = atoms
    for key in ("trajectory", "logfile", "loginterval"):
        if key in t:
            raise InputError(f"[integrator] {key}: outputs are set in [output]")
    t.update(trajectory=paths["trajectory"], logfile=paths["log"], loginterval=interval)
    return make(t, "[integrator]", SpinLatticeDynamics), steps


def _in_folder(folder):
    @contextlib.contextmanager
    def cd():
        here = os.getcwd()
        os.chdir(folder)
        try:
            yield
        finally:
            os.chdir(here)
    return cd()


def run(input_path, steps=None, overwrite=False, progress=True, out=None):
    """``ase-spin run``: build the scene of ``input_path``, integrate, write the
    outputs. Returns the integrator (closed)."""
    out = out or sys.stdout
    input_path = Path(input_path).resolve()
    spec = load_input(input_path)
    with _in_folder(input_path.parent):
        atoms = build_scene(spec)
        nsteps = spec.get("integrator", {}).get("steps", 0) if steps is None else steps
        nsteps = nsteps if isinstance(nsteps, int) and not isinstance(nsteps, bool) else 0
        # the integrator's keywords checked before any output file is touched
        _integrator(atoms, spec, dict.fromkeys(("trajectory", "log")), 1, steps)
        paths, interval = _outputs(spec, input_path.stem, nsteps, overwrite)
        dyn, nsteps = _integrator(atoms, spec, paths, interval, steps)
        if paths["xyz"]:
            from .viewing import write_ovito_xyz

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
    from .md import IntegrationError

    args = _parser().parse_args(argv)
    try:
        if args.command == "run":
            run(args.input, steps=args.steps, overwrite=args.overwrite,
                progress=not args.no_progress)
        elif args.command == "compile":
            from .warmup import compile_kernels

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
