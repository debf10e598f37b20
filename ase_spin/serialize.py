"""Hamiltonians as plain data (JSON-ready dicts) and back.

What ``calc.todict()`` returns and a trajectory keeps as its calculator's
parameters, so that ``SpinLatticeCalculator.from_dict(frame.calc.parameters)``
rebuilds the Hamiltonian of a run. Every term and coupling here is defined by
its constructor's arguments (``_parameters``): a term is written as its class and
those arguments; rebuilt, it passes the same checks as when it was made.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping

import numpy as np

from .terms.ase_calculator import is_ase_calculator
from .terms.parameters import Parameterised

__all__ = ["encode_term", "decode_term"]


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


def _load(path, base, what):
    module, _, name = path.partition(":")
    try:
        obj = importlib.import_module(module)
        for part in name.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as err:
        raise ValueError(f"cannot rebuild {what} {path!r}: {err}") from None
    if not (isinstance(obj, type) and issubclass(obj, base)):
        raise ValueError(f"cannot rebuild {what} from {path!r}: not a {base.__name__}")
    return obj


def decode_term(data):
    """Inverse of :func:`encode_term`. Only ase_spin terms and couplings and
    ASE calculators are built (a class named in the data must be one)."""
    from ase.calculators.calculator import BaseCalculator

    if isinstance(data, list):
        return [decode_term(v) for v in data]
    if not isinstance(data, dict):
        return data
    if "__class__" in data:
        cls = _load(data["__class__"], Parameterised, "the term")
        return cls(**{k: decode_term(v) for k, v in data["args"].items()})
    if "__calculator__" in data:
        cls = _load(data["__calculator__"], BaseCalculator, "the ASE calculator")
        return cls(**decode_term(data["parameters"]))
    if "__mapping__" in data:
        return {k: decode_term(v) for k, v in data["__mapping__"]}
    if "__unserialisable__" in data:
        raise ValueError(f"cannot rebuild a {data['__unserialisable__']} "
                         f"({data['repr']}): it was not written as data; give it again")
    return {k: decode_term(v) for k, v in data.items()}
