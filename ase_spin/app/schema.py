"""Tables that build objects, checked before anything is built: the keys of
an input table against the keywords of the class or function it calls (the
nearest known key for an unknown one; keys without a default; a TOML
true/false only where the keyword is a flag), and classes looked up by name
among those ``ase_spin`` exports (:func:`make`). Used by
:mod:`ase_spin.app.inputs` for every table of the input file."""

from __future__ import annotations

import difflib
import inspect

import ase_spin
import ase_spin.terms

from ..validate import REQUIRED

__all__ = ["InputError", "InputWarning", "take", "label", "nearest", "refuse_unknown", "needs",
           "refuse_flags", "as_written", "check_keywords", "check_table", "make", "is_number"]


class InputError(ValueError):
    """The input file is wrong; the message says where."""


class InputWarning(UserWarning):
    """A value of the input file that runs, but is probably not what was meant;
    the message names the table, the key and its unit."""


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
        raise InputError(f"{label(where)} {key} must be {names}, got {value!r}")
    return value


def label(where):
    """A table's name as the message shows it: ``structure`` -> ``[structure]``
    (labels such as ``[[terms]] #2 (EAM)`` as they are)."""
    return where if where.startswith("[") else f"[{where}]"


def nearest(word, choices, form="'{}'"):
    """`` (did you mean 'x'?)`` for the closest of ``choices``, or ''."""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {form.format(close[0])}?)" if close else ""


def refuse_unknown(table, where, allowed=None):
    """Raise InputError naming the keys of ``table`` that are not ``allowed``
    (all of them if ``allowed`` is None: the keys left after the known ones
    were taken), each with the nearest allowed key where one is close."""
    allowed = () if allowed is None else tuple(allowed)
    unknown = [k for k in table if k not in allowed]
    if not unknown:
        return
    problems = [f"unknown key {k!r} in {label(where)}{nearest(str(k), allowed)}"
                for k in unknown]
    if not any("did you mean" in p for p in problems) and allowed:
        problems[-1] += f" (its keys: {', '.join(allowed)})"
    raise InputError("; ".join(problems))


def needs(where, missing, units_of=None):
    units_of = units_of or {}
    names = [f"{k!r}" + (f" ({units_of[k][0]})" if k in units_of else "") for k in missing]
    return InputError(f"{label(where)} needs {' and '.join(names)}")


def _keywords(function):
    """(accepted, required): the names ``function(**keywords)`` takes and those
    it needs (no default); a class's ``**kwargs`` passed on to its bases'
    ``__init__`` are followed up its MRO. None where they cannot be told
    (no signature, or ``**kwargs`` to the end)."""
    try:
        own = inspect.signature(function)
    except (TypeError, ValueError):
        return None
    keyword = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    # (REQUIRED: a keyword the function checks for itself, after unknown ones)
    required = [p.name for p in own.parameters.values()
                if p.kind in keyword and (p.default is inspect.Parameter.empty
                                          or p.default is REQUIRED)]
    if inspect.isclass(function):
        inits = [vars(c)["__init__"] for c in function.__mro__
                 if c is not object and "__init__" in vars(c)]
    else:
        inits = [function]
    accepted = []
    for init in inits:
        try:
            parameters = list(inspect.signature(init).parameters.values())
        except (TypeError, ValueError):
            return None
        if init is not function:
            parameters = parameters[1:]  # self
        for p in parameters:
            if p.kind in keyword and p.name not in accepted:
                accepted.append(p.name)
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters):
            return accepted, required
    return None


def _flag_keywords(function):
    """The keywords of ``function`` (a class: of its ``__init__`` up the MRO)
    whose default is True or False: the only ones a TOML true/false may set."""
    functions = ([vars(c)["__init__"] for c in function.__mro__
                  if c is not object and "__init__" in vars(c)]
                 if inspect.isclass(function) else [function])
    flags = set()
    for f in functions:
        try:
            parameters = inspect.signature(f).parameters.values()
        except (TypeError, ValueError):
            continue
        flags.update(p.name for p in parameters if isinstance(p.default, bool))
    return flags


def _holds_flag(value):
    """True if ``value`` is or holds (in lists, or tables without a ``type``,
    which are checked as tables of their own) a true/false."""
    if isinstance(value, bool):
        return True
    if isinstance(value, list):
        return any(_holds_flag(v) for v in value)
    if isinstance(value, dict) and "type" not in value:
        return any(_holds_flag(v) for v in value.values())
    return False


def refuse_flags(table, where, function, skip=("type",)):
    """Refuse a TOML true/false in a key of ``table`` whose keyword of
    ``function`` does not default to True/False: Python would take true for 1
    (``order = true`` an order 1, ``direction = [0, 0, true]`` a unit vector)."""
    flags = _flag_keywords(function)
    for key, value in table.items():
        if key not in skip and key not in flags and _holds_flag(value):
            raise InputError(f"{label(where)} {key} = {as_written(value)}: true/false where a "
                             "value is expected (true is not taken for 1)")


def as_written(value):
    """A value as the input file wrote it (true/false, not True/False)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return "[" + ", ".join(as_written(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {as_written(v)}" for k, v in value.items()) + "}"
    return repr(value) if isinstance(value, str) else str(value)


def check_keywords(keys, function, where, given=(), hidden=(), units_of=None, extra=()):
    """Refuse, before ``function`` is called, the ``keys`` of an input table
    that it does not take (with the nearest it does) and the keywords it needs
    that are missing. ``given``: keywords the program passes itself (not from
    the file); ``hidden``: keywords it takes that a file may not set;
    ``extra``: keys of the table the program takes itself."""
    found = _keywords(function)
    if found is None:
        return
    accepted, required = found
    allowed = list(extra) + [k for k in accepted
                             if k not in given and k not in hidden and k not in extra]
    refuse_unknown(dict.fromkeys(keys), where, allowed)
    missing = [k for k in required if k not in keys and k not in given]
    if missing:
        raise needs(where, missing, units_of)


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


def _class_of(spec, where, base, nested=False):
    """The class named by a table's ``type``: exported by ase_spin, a subclass
    of ``base`` (``nested``: a table inside a term, which builds a coupling)."""
    name = spec.get("type")
    choices = _exported(base)
    if not isinstance(name, str):
        raise InputError(f"{where} needs type = one of {', '.join(sorted(choices))}")
    if name not in choices:
        if nested and name in _exported(object):
            raise InputError(f"{where}: type {name!r} is not built here: a table inside a "
                             "[[terms]] table builds a coupling, one of "
                             f"{', '.join(sorted(choices))}")
        raise InputError(f"{where}: unknown type {name!r}{nearest(name, choices)}; choose "
                         f"one of {', '.join(sorted(choices))}")
    return choices[name]


def check_table(spec, where, base=object, given=(), hidden=(), units_of=None, extra=(),
                nested=None, inside=False):
    """Check a table that builds an object (``type`` and keywords), and the
    tables with a ``type`` inside it, without building anything: the type is
    known, the keys are the class's keywords (:func:`check_keywords`), no
    true/false where the keyword is not a flag (:func:`refuse_flags`).
    ``nested``: the base class a table with a ``type`` inside it may build
    (None: no such table; ``inside``: this table is one). Returns the class."""
    cls = _class_of(spec, where, base, inside)
    keys = [k for k in spec if k != "type"]
    label = f"{where} ({spec['type']})"
    check_keywords(keys, cls, label, given, hidden, units_of, extra)
    refuse_flags(spec, label, cls)
    for k in keys:
        _check_nested(spec[k], f"{where}.{k}", nested)
    return cls


def _check_nested(v, where, nested):
    if isinstance(v, dict):
        if "type" in v:
            if nested is None:
                raise InputError(f"{where}: a table with a type builds a coupling inside a "
                                 "[[terms]] table only; nothing is built from it here")
            check_table(v, where, nested, nested=nested, inside=True)
        else:
            for k, x in v.items():
                _check_nested(x, f"{where}.{k}", nested)
    elif isinstance(v, list):
        for k, x in enumerate(v):
            _check_nested(x, f"{where}[{k}]", nested)


def make(spec, where, base=object, given=None, hidden=(), units_of=None, extra=(),
         nested=None, inside=False):
    """Build ``spec["type"](**rest, **given)``: a class exported by ase_spin, a
    subclass of ``base``; nested tables with a ``type`` key build subclasses
    of ``nested`` the same way (None: none may). Everything is checked first
    (:func:`check_table`); ``given``: keywords the program passes itself, not
    from the file."""
    given = dict(given or {})
    cls = check_table(spec, where, base, given, hidden, units_of, extra, nested, inside)
    label = f"{where} ({spec['type']})"
    kwargs = {k: _value(v, f"{where}.{k}", nested) for k, v in spec.items() if k != "type"}
    try:
        return cls(**kwargs, **given)
    except (TypeError, ValueError) as err:
        raise InputError(f"{label}: {err}") from None


def _value(v, where, nested):
    if isinstance(v, dict):
        if "type" in v:
            return make(v, where, nested, nested=nested, inside=True)
        return {k: _value(x, f"{where}.{k}", nested) for k, x in v.items()}
    if isinstance(v, list):
        return [_value(x, f"{where}[{k}]", nested) for k, x in enumerate(v)]
    return v

def is_number(x):
    """An int or a float of the file, not a true/false."""
    return isinstance(x, (int, float)) and not isinstance(x, bool)
