"""The input file of ``ase-spin run`` (TOML): reading it, checking it, and
building the scene and the integrator it describes (docs/command_line.md).

Terms, couplings and integrators are looked up by name among the classes
``ase_spin`` exports: a term added to the package (and exported) is usable
here with no change to this file. A table with a ``type`` key anywhere inside
a term's parameters builds that coupling (``coupling = {type = "BetheSlater",
J1 = ...}``; :data:`NESTED`), and nothing else is built from a nested table;
every other key is a keyword argument, checked against the class's signature
(unknown keys, with the nearest known one; keys without a default; a
true/false for a keyword that is not a flag) before the class is called.

Units: every quantity is in the unit docs/command_line.md's table gives it;
times are in fs. The keys whose unit differs from the Python API's (ASE time
units) are those of :data:`UNITS`, converted here and nowhere else
(:func:`build_integrator`).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np
from ase import units

import ase_spin

from ..calculator import SpinLatticeCalculator
from ..hamiltonian import Hamiltonian
from ..md import SpinLatticeDynamics
from ..md.errors import TimestepWarning
from ..spins import get_moments, split_moments
from ..terms import Coupling, Term
from ..validate import warn_user
from .schema import (InputError, InputWarning, as_written, check_keywords, check_table,
                     is_number, label, make, nearest, needs, refuse_flags, refuse_unknown, take)

__all__ = ["load_input", "check_input", "build_scene", "build_integrator", "in_folder", "make",
           "take", "refuse_unknown", "check_keywords", "check_table", "refuse_flags",
           "warn_implausible", "in_input_words", "files_read", "InputError", "InputWarning",
           "UNITS", "TABLE_KEYS", "NESTED"]

_TABLES = ("structure", "spins", "velocities", "terms", "calculator", "integrator", "output")

#: What a table with a ``type`` inside a [[terms]] table may build (the
#: documented schema: couplings); nowhere else does a nested table build
#: anything (a file must not make, say, a logger, which opens the file it names).
NESTED = Coupling

#: The keys of the tables with fixed keys ([[terms]] and [integrator] take
#: their class's keywords).
TABLE_KEYS = {
    "structure": ("file", "index", "format", "build", "repeat", "rattle", "seed"),
    "spins": ("magnitude", "direction", "cone", "seed"),
    "velocities": ("temperature", "seed"),
    "calculator": ("skin", "conventions"),
    "output": ("trajectory", "log", "xyz", "interval", "overwrite"),
}

#: [integrator] keys given in the input file in other units than the Python
#: API's: key -> (the file's unit, its value in ASE units). Times are in fs
#: throughout the file, so a rate is in 1/fs (ASE's own advice for its
#: Langevin, ``friction=0.01 / units.fs``, is ``friction = 0.01`` here).
UNITS = {
    "timestep": ("fs", units.fs),
    "friction": ("1/fs", 1.0 / units.fs),
    "hbar": ("eV·fs", units.fs),
}

#: Keywords of ASE's dynamics that the program sets itself (outputs in [output])
#: or that have no meaning in a file.
_OUTPUT_KEYWORDS = ("trajectory", "logfile", "loginterval", "append_trajectory")
_NOT_FROM_FILES = ("atoms", "comm", "master")
#: How [integrator]'s keys are checked: the program passes ``_GIVEN`` itself (the
#: timestep converted from the file's fs; the outputs are [output]'s).
_GIVEN = ("atoms", "timestep", "trajectory", "logfile", "loginterval")
_INTEGRATOR_CHECK = {"hidden": _OUTPUT_KEYWORDS + _NOT_FROM_FILES, "units_of": UNITS,
                     "extra": ("steps", "timestep")}


# -- reading the input ----------------------------------------------------------

def _toml():
    try:
        import tomllib
    except ModuleNotFoundError:  # Python < 3.11
        import tomli as tomllib
    return tomllib


def load_input(path):
    """The input file as a dict, its tables checked against the known ones and
    the keys of the fixed tables against theirs (:data:`TABLE_KEYS`)."""
    tomllib = _toml()
    path = Path(path)
    if not path.is_file():
        raise InputError(f"input file {str(path)!r} not found")
    with open(path, "rb") as fd:
        try:
            spec = tomllib.load(fd)
        except tomllib.TOMLDecodeError as err:
            raise InputError(f"{str(path)!r} is not valid TOML: {err}") from None
    unknown = [name for name in spec if name not in _TABLES]
    if unknown:
        raise InputError("; ".join(
            f"unknown table [{name}] in {str(path)!r}{nearest(name, _TABLES, '[{}]')}"
            for name in unknown) + f" (the tables are {', '.join(_TABLES)})")
    for name in _TABLES:
        want = list if name == "terms" else dict
        if name in spec and not isinstance(spec[name], want):
            form = "[[terms]] tables" if want is list else f"a [{name}] table"
            raise InputError(f"{name} must be {form}, got {spec[name]!r}")
    check_input(spec)
    return spec


# -- the scene ---------------------------------------------------------------------

def _structure(table):
    from ase import build
    from ase.io import read

    refuse_unknown(table, "structure", TABLE_KEYS["structure"])
    t = dict(table)
    if ("file" in t) == ("build" in t):
        raise InputError("[structure] needs either 'file' (a file ase.io.read reads) or "
                         "'build' = {function = \"bulk\", ...} (a function of ase.build)")
    if "file" in t:
        path = take(t, "structure", "file", kind=str)
        index = take(t, "structure", "index", -1, (int, str))
        fmt = take(t, "structure", "format", None, str)
        if not Path(path).is_file():
            raise InputError(f"[structure] file {path!r} not found (relative paths are "
                             f"relative to the input file's folder)")
        atoms = read(path, index=index, format=fmt)
        if isinstance(atoms, list):
            raise InputError(f"[structure] index {index!r} selects {len(atoms)} frames; "
                             "give one frame")
    else:
        recipe = dict(take(t, "structure", "build", kind=dict))
        function = recipe.pop("function", None)
        names = sorted(n for n in getattr(build, "__all__", dir(build))
                       if not n.startswith("_") and callable(getattr(build, n)))
        if function not in names:
            raise InputError(f"[structure] build.function must be a function of ase.build"
                             f"{nearest(str(function), names)} ({', '.join(names)}); got "
                             f"{function!r}")
        check_keywords(recipe, getattr(build, function), f"[structure] build = {function}(...)")
        refuse_flags(recipe, f"[structure] build = {function}(...)", getattr(build, function))
        try:
            atoms = getattr(build, function)(**recipe)
        except (TypeError, ValueError, KeyError, RuntimeError) as err:
            raise InputError(f"[structure] build = {function}(...): {err}") from None
    repeat = take(t, "structure", "repeat", None, (int, list))
    if repeat is not None and not (
            (isinstance(repeat, int) and repeat >= 1)
            or (isinstance(repeat, list) and len(repeat) == 3 and all(
                isinstance(r, int) and not isinstance(r, bool) and r >= 1 for r in repeat))):
        raise InputError(f"[structure] repeat must be a positive integer or three of them, "
                         f"got {as_written(repeat)}")
    if repeat is not None:
        atoms = atoms.repeat(repeat)
    rattle = take(t, "structure", "rattle", 0.0, (int, float))
    if not 0.0 <= rattle < np.inf:
        raise InputError(f"[structure] rattle must be a finite number >= 0 (Å), got {rattle}")
    seed = take(t, "structure", "seed", 0, int)
    if rattle:
        atoms.rattle(float(rattle), seed=seed)
    return atoms


def _spins(atoms, table):
    refuse_unknown(table, "spins", TABLE_KEYS["spins"])
    t = dict(table)
    rng = np.random.default_rng(take(t, "spins", "seed", 0, int))
    n = len(atoms)
    magnitude = take(t, "spins", "magnitude", None, (int, float, dict))
    if isinstance(magnitude, dict):
        symbols = atoms.get_chemical_symbols()
        missing = sorted(set(symbols) - set(magnitude))
        if missing:
            raise InputError(f"[spins] magnitude has no value for {', '.join(missing)} "
                             "(give 0 for a non-magnetic species)")
        stray = sorted(set(magnitude) - set(symbols))
        if stray:
            raise InputError(f"[spins] magnitude has a value for {', '.join(stray)}, which "
                             f"the structure does not have (its species: "
                             f"{', '.join(sorted(set(symbols)))})")
        for symbol, value in magnitude.items():
            if not is_number(value):
                raise InputError(f"[spins] magnitude {symbol} must be a number (μB), got "
                                 f"{as_written(value)}")
        magnitude = np.array([float(magnitude[s]) for s in symbols])
    direction = take(t, "spins", "direction", None, (list, str))
    if isinstance(direction, list) and (len(direction) != 3 or not all(
            is_number(x) for x in direction)):
        raise InputError(f'[spins] direction must be three numbers or "random", got '
                         f"{as_written(direction)}")
    cone = take(t, "spins", "cone", None, (int, float))
    if cone is not None and not 0.0 <= cone <= 180.0:
        raise InputError(f"[spins] cone must be a half-angle from 0 to 180 (degrees), got {cone}")
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

    refuse_unknown(table, "velocities", TABLE_KEYS["velocities"])
    t = dict(table)
    temperature = take(t, "velocities", "temperature", None, (int, float))
    seed = take(t, "velocities", "seed", 0, int)
    if temperature is None:
        raise InputError("[velocities] needs 'temperature' (K)")
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
        built.append(make(term, f"[[terms]] #{k + 1}", Term, nested=NESTED))
    calc = dict(spec.get("calculator", {}))
    refuse_unknown(calc, "calculator", TABLE_KEYS["calculator"])
    skin = take(calc, "calculator", "skin", 0.3, (int, float))
    conventions = take(calc, "calculator", "conventions", "physical", str)
    try:
        atoms.calc = SpinLatticeCalculator(built, skin=skin, conventions=conventions)
    except ValueError as err:
        raise InputError(f"[calculator] {err}") from None
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
    _bind_terms(atoms, built, skin)
    return atoms


def _bind_terms(atoms, terms, skin):
    """Bind the terms to the structure now (its species, through an EAM file's
    element map, its cell and moments), so that a mismatch is refused before
    anything runs, naming the [[terms]] table it comes from."""
    try:
        atoms.calc.bound_evaluator(atoms)
    except (ValueError, TypeError, KeyError) as err:
        mu = split_moments(get_moments(atoms))[1]
        for k, term in enumerate(terms):
            try:
                Hamiltonian([term], skin=skin).bind(atoms.numbers, atoms.cell.array,
                                                     atoms.pbc, mu)
            except (ValueError, TypeError, KeyError) as own:
                raise InputError(f"[[terms]] #{k + 1} ({type(term).__name__}): "
                                 f"{_text(own)}") from None
        raise InputError(f"[structure]: {_text(err)}") from None


def _text(err):
    return err.args[0] if isinstance(err, KeyError) and err.args else str(err)


def _to_ase_units(table, where="integrator"):
    """The file's values of :data:`UNITS` in ASE units, in place: the one place
    where the input file's units become the Python API's. Checked first, in
    the file's units: numbers, > 0 for the timestep and ħ, >= 0 for a rate."""
    for key, (unit, factor) in UNITS.items():
        if key not in table:
            continue
        value = take(table, where, key, kind=(int, float))
        positive = key in ("timestep", "hbar")
        if not (value > 0 if positive else value >= 0):
            raise InputError(f"{label(where)} {key} = {value!r} ({unit}) must be "
                             f"{'> 0' if positive else '>= 0'}")
        table[key] = float(value) * factor


def build_integrator(atoms, spec, paths, interval, steps_override):
    """The integrator of an input dict's [integrator] table on ``atoms``, writing to
    ``paths`` (trajectory, log) every ``interval`` steps; returns (it, steps):
    ``steps_override`` or the table's ``steps``. The table's keys are checked
    against the integrator's keywords before it is built, and its values of
    :data:`UNITS` converted to ASE units."""
    t = _integrator_table(spec)
    steps = take(t, "integrator", "steps", None, int)
    if steps_override is not None:
        steps = steps_override
    if steps is None:
        raise needs("integrator", ["steps"])
    if steps < 0:
        raise InputError(f"[integrator] steps must be >= 0, got {steps}")
    if "timestep" not in t:
        raise needs("integrator", ["timestep"], UNITS)
    _to_ase_units(t)
    given = {"atoms": atoms, "timestep": t.pop("timestep"), "trajectory": paths["trajectory"],
             "logfile": paths["log"], "loginterval": interval}
    dyn = make(t, "[integrator]", SpinLatticeDynamics, given=given, **_INTEGRATOR_CHECK)
    return dyn, steps



def _integrator_table(spec):
    """A copy of the [integrator] table, its type defaulted, output keywords refused."""
    t = dict(spec.get("integrator", {}))
    t.setdefault("type", "CollectivePRK")
    for key in _OUTPUT_KEYWORDS:
        if key in t:
            raise InputError(f"[integrator] {key}: outputs are set in [output]")
    return t


def check_input(spec):
    """Check every table's keys, before anything is built: the fixed tables'
    (:data:`TABLE_KEYS`), each [[terms]] table's and [integrator]'s against
    their class's keywords (nested ``type`` tables too)."""
    for name, keys in TABLE_KEYS.items():
        refuse_unknown(spec.get(name, {}), name, keys)
    for k, term in enumerate(spec.get("terms", [])):
        if not isinstance(term, dict):
            raise InputError(f"[[terms]] #{k + 1} must be a table, got {term!r}")
        check_table(term, f"[[terms]] #{k + 1}", Term, nested=NESTED)
    # steps and timestep are checked when built (--steps may stand for steps)
    check_table(_integrator_table(spec), "[integrator]", SpinLatticeDynamics, given=_GIVEN,
                **_INTEGRATOR_CHECK)


def warn_implausible(spec, steps):
    """Warn (:class:`InputWarning`) about values that run but are probably not
    what was meant, naming the key and its unit: a lattice bath whose
    relaxation time 1/friction is longer than the run (the lattice stays far
    from the bath temperature) or shorter than a step (overdamped: its motion
    is mostly noise)."""
    t = spec.get("integrator", {})
    friction, timestep = t.get("friction"), t.get("timestep")
    if not (_positive_number(friction) and _positive_number(timestep)):
        return
    tau = 1.0 / friction
    typical = ("typical values are 0.001 to 0.1 (1/fs): ASE's friction=0.01/units.fs is "
               "0.01 here, LAMMPS's fix langevin damp 0.1 ps (metal units) is 0.01")
    key = f"friction = {friction:g} (1/fs) in [integrator]"
    if steps and tau > steps * timestep:
        warn_user(f"{key}: the lattice relaxes towards the bath temperature over "
                  f"1/friction = {tau:.4g} fs, longer than the whole run ({steps} steps "
                  f"x {timestep:g} fs = {steps * timestep:.4g} fs), so it stays far from "
                  f"it; {typical}", InputWarning)
    elif tau < timestep:
        warn_user(f"{key}: 1/friction = {tau:.3g} fs is shorter than a step "
                  f"({timestep:g} fs): the lattice is overdamped, its motion mostly "
                  f"noise; {typical}", InputWarning)


def _positive_number(x):
    return is_number(x) and x > 0




def files_read(spec):
    """The files an input dict reads, as {what: path} (paths as written, relative
    to the current folder): the structure file, and every string of a
    [[terms]] table that names an existing file (an EAM potential). Outputs
    must not be any of them (:func:`ase_spin.app.cli.run`)."""
    found = {}
    structure = spec.get("structure", {})
    if isinstance(structure.get("file"), str):
        found["the structure file ([structure] file)"] = structure["file"]

    def strings(value, where):
        if isinstance(value, str):
            with contextlib.suppress(OSError, ValueError):
                if Path(value).is_file():
                    found[f"a file the terms read ({where})"] = value
        elif isinstance(value, dict):
            for k, v in value.items():
                strings(v, f"{where}.{k}")
        elif isinstance(value, list):
            for k, v in enumerate(value):
                strings(v, f"{where}[{k}]")

    for k, term in enumerate(spec.get("terms", [])):
        strings(term, f"[[terms]] #{k + 1}")
    return found


def in_input_words(warning):
    """A warning's text for a user of input files: a :class:`TimestepWarning`
    (worded by the integrator for Python callers) as the input file's
    ``timestep = ... (fs)`` in [integrator], from its figures; others as they
    are."""
    if isinstance(warning, TimestepWarning):
        return (f"timestep = {warning.timestep_fs:.4g} (fs) in [integrator]: "
                f"{'; '.join(warning.problems)}; {warning.advice}")
    return str(warning)


def in_folder(folder):
    """A context in which the current folder is ``folder`` (an input file's paths
    are relative to its own folder)."""
    @contextlib.contextmanager
    def cd():
        here = os.getcwd()
        os.chdir(folder)
        try:
            yield
        finally:
            os.chdir(here)
    return cd()
