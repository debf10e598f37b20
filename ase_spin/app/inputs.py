"""The input file of ``ase-spin run`` (TOML): reading it and building the scene
and the integrator it describes (docs/command_line.md).

Terms, couplings and integrators are looked up by name among the classes
``ase_spin`` exports: a term added to the package (and exported) is usable
here with no change to this file. A table with a ``type`` key anywhere inside
a term's parameters builds that object (``coupling = {type = "BetheSlater",
J1 = ...}``); every other key is a keyword argument, in the class's own units —
only the integrator's ``timestep`` is given in fs here.
"""

from __future__ import annotations

import contextlib
import inspect
import os
from pathlib import Path

import numpy as np
from ase import units

import ase_spin
import ase_spin.terms

from ..calculator import SpinLatticeCalculator
from ..md import SpinLatticeDynamics
from ..terms import Term

__all__ = ["load_input", "build_scene", "build_integrator", "in_folder", "make", "take",
           "refuse_unknown", "InputError"]

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


def take(table, where, key, default=None, kind=None):
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


def refuse_unknown(table, where):
    """Raise InputError naming the keys left in ``table`` (none may be)."""
    if table:
        raise InputError(f"[{where}] has unknown key(s) {', '.join(sorted(table))}")


# -- objects by name --------------------------------------------------------------

def _exported(base):
    """Classes ase_spin exports that derive from ``base``, by name (the
    abstract bases of terms excluded)."""
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
            raise InputError(f"[structure] build.function must be a function of ase.build "
                             f"({', '.join(names)}); got {function!r}")
        try:
            atoms = getattr(build, function)(**recipe)
        except (TypeError, ValueError, KeyError, RuntimeError) as err:
            raise InputError(f"[structure] build = {function}(...): {err}") from None
    repeat = take(t, "structure", "repeat", None, (int, list))
    if repeat is not None:
        atoms = atoms.repeat(repeat)
    rattle = take(t, "structure", "rattle", 0.0, (int, float))
    seed = take(t, "structure", "seed", 0, int)
    if rattle:
        atoms.rattle(float(rattle), seed=seed)
    refuse_unknown(t, "structure")
    return atoms


def _spins(atoms, table):
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
        magnitude = np.array([float(magnitude[s]) for s in symbols])
    direction = take(t, "spins", "direction", None, (list, str))
    cone = take(t, "spins", "cone", None, (int, float))
    refuse_unknown(t, "spins")
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
    temperature = take(t, "velocities", "temperature", None, (int, float))
    seed = take(t, "velocities", "seed", 0, int)
    refuse_unknown(t, "velocities")
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
    skin = take(calc, "calculator", "skin", 0.3, (int, float))
    refuse_unknown(calc, "calculator")
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


def build_integrator(atoms, spec, paths, interval, steps_override):
    """The integrator of an input dict's [integrator] table on ``atoms``, writing to
    ``paths`` (trajectory, log) every ``interval`` steps; returns (it, steps):
    ``steps_override`` or the table's ``steps``."""
    t = dict(spec.get("integrator", {}))
    t.setdefault("type", "CollectivePRK")
    steps = take(t, "integrator", "steps", None, int)
    if steps_override is not None:
        steps = steps_override
    if steps is None or steps < 0:
        raise InputError(f"[integrator] needs steps = a number >= 0, got {steps!r}")
    timestep = take(t, "integrator", "timestep", None, (int, float))
    if timestep is None or not timestep > 0:
        raise InputError(f"[integrator] needs timestep = ... (fs, > 0), got {timestep!r}")
    t["timestep"] = float(timestep) * units.fs
    t["atoms"] = atoms
    for key in ("trajectory", "logfile", "loginterval"):
        if key in t:
            raise InputError(f"[integrator] {key}: outputs are set in [output]")
    t.update(trajectory=paths["trajectory"], logfile=paths["log"], loginterval=interval)
    return make(t, "[integrator]", SpinLatticeDynamics), steps


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
