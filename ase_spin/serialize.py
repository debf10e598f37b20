"""Hamiltonians as plain data (JSON-ready dicts) and back.

What ``calc.todict()`` returns and a trajectory keeps as its calculator's
parameters, so that ``SpinLatticeCalculator.from_dict(frame.calc.parameters)``
rebuilds the Hamiltonian of a run. Every term and coupling here is defined by
its constructor's arguments (``_parameters``): a term is written as its class and
those arguments; rebuilt, it passes the same checks as when it was made.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .terms.ase_calculator import is_ase_calculator
from .terms.parameters import Parameterised

__all__ = ["encode_term", "decode_term", "own_classes", "allowed_factories"]


def _class_path(obj):
    cls = type(obj)
    return f"{cls.__module__}:{cls.__qualname__}"


def encode_term(value):
    """A term, coupling, ASE calculator or parameter value as JSON-ready data."""
    if isinstance(value, Parameterised):
        return {"__class__": _class_path(value),
                "args": {arg: encode_term(getattr(value, attr))
                         for arg, attr in value._parameters.items()}}
    if is_ase_calculator(value):
        params = value.todict() if hasattr(value, "todict") else {}
        return {"__calculator__": _class_path(value), "parameters": encode_term(params)}
    if isinstance(value, Mapping):
        # per-pair keys ("Fe", "Co") become "Co-Fe", which the terms accept
        return {"__mapping__": [["-".join(k) if isinstance(k, tuple) else k, encode_term(v)]
                                for k, v in value.items()]}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [encode_term(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return {"__unserialisable__": f"{type(value).__module__}.{type(value).__qualname__}",
            "repr": repr(value)[:200]}


def own_classes():
    """``"module:Qualname"`` -> class for every term and coupling class defined
    in ase_spin (the subclasses of :class:`Parameterised` in its modules): what
    :func:`decode_term` builds from data without being asked. Nothing is
    imported to find them; a class named in data is only looked up here."""
    found = {}
    stack = [Parameterised]
    while stack:
        for sub in stack.pop().__subclasses__():
            stack.append(sub)
            module = sub.__module__
            if module == "ase_spin" or module.startswith("ase_spin."):
                found[f"{module}:{sub.__qualname__}"] = sub
    return found


def allowed_factories(allow):
    """The caller's opt-in of :func:`decode_term` as {name: factory}: a
    mapping from the name data gives (``"module:Qualname"``, as
    :func:`encode_term` writes it, or the bare class name) to a callable taking
    the written arguments as keywords; or an iterable of classes, each allowed
    under its ``"module:Qualname"``."""
    if allow is None:
        return {}
    if isinstance(allow, Mapping):
        out = {}
        for name, factory in allow.items():
            if not isinstance(name, str) or not callable(factory):
                raise TypeError("allow= maps a class name written in the data (such as "
                                "'ase.calculators.emt:EMT' or 'EMT') to a callable, got "
                                f"{name!r}: {factory!r:.60}")
            out[name] = factory
        return out
    if isinstance(allow, (str, bytes, type)):
        allow = [allow]
    out = {}
    for cls in allow:
        if not isinstance(cls, type):
            raise TypeError("allow= takes classes (such as ase.calculators.emt.EMT) or a "
                            f"mapping of names to factories, got {cls!r:.60}")
        out[f"{cls.__module__}:{cls.__qualname__}"] = cls
    return out


def _factory(path, allowed):
    """The caller's factory for the class ``path`` written in data, by its full
    name or its bare class name, or None."""
    if path in allowed:
        return allowed[path]
    bare = path.rpartition(":")[2].rpartition(".")[2]
    return allowed.get(bare)


def _refused(path, what):
    name = path.rpartition(":")[2].rpartition(".")[2] or path
    return ValueError(f"refused to build {what} {path!r} from data: {_REASONS[what]}; to "
                      f"build it, pass allow=[{name}] (the class) or allow={{'{name}': "
                      "factory} to from_dict, for data you trust (docs/errors.md, "
                      "\"What data may run\")")


_REASONS = {
    "the term": "only ase_spin's own terms and couplings are built from data unless the "
                "caller allows others",
    "the ASE calculator": "ASE calculators are built from data only when the caller allows "
                          "them (a calculator's parameters can name programs it runs)",
}


def _class_name(data, key):
    path = data[key]
    if not isinstance(path, str):
        raise TypeError(f"cannot rebuild a term: {key} must be a 'module:Class' string, got "
                        f"{path!r:.80}")
    return path


def _keywords(data, key, path):
    args = data.get(key, {})
    if not isinstance(args, dict) or not all(isinstance(k, str) for k in args):
        raise ValueError(f"cannot rebuild {path!r}: its {key!r} must be a mapping of keyword "
                         f"names to values, got {args!r:.80}")
    return args


def decode_term(data, allow=None):
    """Inverse of :func:`encode_term`.

    What data may build is an allow-list: the terms and couplings of ase_spin
    (:func:`own_classes`), looked up by the name the data gives, never
    imported. An ASE calculator (``"__calculator__"``) or any other class is
    built only when the caller names it in ``allow`` (see
    :func:`allowed_factories`): a crafted file must not choose the code that
    runs (importing a module runs it; a calculator's parameters can name the
    program it starts). A refused class is a ValueError naming it."""
    allowed = allowed_factories(allow)
    try:
        return _decode(data, allowed, own_classes())
    except RecursionError:
        raise ValueError("cannot rebuild the terms: the data is nested too deeply (it was "
                         "not written by encode_term)") from None


def _decode(data, allowed, own):
    if isinstance(data, list):
        return [_decode(v, allowed, own) for v in data]
    if not isinstance(data, dict):
        return data
    if "__class__" in data:
        path = _class_name(data, "__class__")
        factory = _factory(path, allowed) or own.get(path)
        if factory is None:
            raise _refused(path, "the term")
        args = _keywords(data, "args", path)
        return factory(**{k: _decode(v, allowed, own) for k, v in args.items()})
    if "__calculator__" in data:
        path = _class_name(data, "__calculator__")
        factory = _factory(path, allowed)
        if factory is None:
            raise _refused(path, "the ASE calculator")
        args = _keywords(data, "parameters", path)
        return factory(**{k: _decode(v, allowed, own) for k, v in args.items()})
    if "__mapping__" in data:
        items = data["__mapping__"]
        if not isinstance(items, list) or not all(
                isinstance(kv, list) and len(kv) == 2 for kv in items):
            raise ValueError(f"cannot rebuild a mapping from {items!r:.80}: a list of "
                             "[key, value] pairs is written")
        return {k if not isinstance(k, list) else tuple(k): _decode(v, allowed, own)
                for k, v in items}
    if "__unserialisable__" in data:
        raise ValueError(f"cannot rebuild a {data['__unserialisable__']} "
                         f"({data.get('repr')}): it was not written as data; give it again")
    return {k: _decode(v, allowed, own) for k, v in data.items()}
