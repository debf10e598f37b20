"""The fuzz campaign: bad inputs of every family, mutations between runs,
interrupts at every point of a step, truncated files.

Each case sets up a small scene, does one thing a hostile user might do, and is
judged by :func:`run_case`:

- ``ok-error``: a documented exception (TypeError, ValueError, an
  ``ase_spin.IntegrationError``, FileExistsError) whose message names the
  problem, with the Atoms bit for bit as before;
- ``ok-result``: a finite result that the case's own check accepts (for
  mutations: equal to a fresh integrator's);
- ``bad-error``: another exception type, or a message that does not name the
  problem;
- ``atoms-changed``: a documented exception, but the Atoms were modified;
- ``silent-wrong``: no exception, and a non-finite or wrong result;
- ``crash``: the process died (only seen by :func:`run_isolated`, which runs
  cases in a child process and starts a new one after a death);
- ``security``: data ran code or wrote where it was not asked to (a module
  named in data imported, a calculator built from data, a file created by a
  deck name or an input file's nested table), and ``data-loss``: a file was
  destroyed (an output replacing the input): seen by the case's own check,
  which raises :class:`Breach`, whatever the call raised.

``python tests/fuzz.py [--quick] [--family NAME ...]`` runs the campaign and
prints the counts by family and verdict; tests/test_fuzz.py runs a fast subset in
the default test run and the whole campaign with ``-m slow``.
"""

from __future__ import annotations

import copy
import json
import math
import os
import subprocess
import sys
import tempfile
import traceback
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from ase import Atoms, units
from ase.build import bulk
from ase.constraints import FixAtoms

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import ase_spin  # noqa: E402
from conftest import PACKAGE_PATH, interrupted_at  # noqa: E402
from ase_spin import (BetheSlater, CollectivePRK, Cubic, Exchange, IntegrationError,  # noqa: E402
                      LennardJones, SpinLatticeCalculator, SuzukiTrotter)
from ase_spin.app import cli  # noqa: E402

DOCUMENTED = (TypeError, ValueError, IntegrationError, FileExistsError)
VERDICTS = ("ok-error", "ok-result", "bad-error", "atoms-changed", "silent-wrong", "crash",
            "security", "data-loss")


class Breach(Exception):
    """Raised by a case's own check: the call ran code or wrote where it was not
    asked to (``verdict`` "security") or destroyed a file ("data-loss")."""

    def __init__(self, verdict, detail):
        super().__init__(detail)
        self.verdict = verdict

CO_LJ = dict(epsilon=0.4, sigma=2.2742, rc=4.7)
CO_BS = (0.0446928, 0.003496, 1.4885)
DT = 0.2 * units.fs

# Special values: IEEE edges, wrong kinds.
FLOAT_EDGES = [0.0, -0.0, 5e-324, -5e-324, 1e-310, 1e-160, 1e-100, 1.0, -1.0, 1e100, 1e154,
               1e200, 1e308, -1e308, math.nan, math.inf, -math.inf]
WRONG_KINDS = ["1", b"1", 1j, 1 + 0j, True, None, object(), [1.0], {"a": 1}]


def terms():
    return [LennardJones(**CO_LJ, cutoff="shift"), Exchange(BetheSlater(*CO_BS), rc=4.0)]


def scene(seed=0, n=(2, 1, 1)):
    """8 rattled fcc Co atoms, spins in a cone, momenta at a few hundred K."""
    a = bulk("Co", "fcc", a=3.54, cubic=True).repeat(n)
    a.rattle(0.05, seed=seed)
    rng = np.random.default_rng(seed)
    ase_spin.set_spins(a, rng.normal(size=(len(a), 3)) + [0, 0, 2.5], 1.7)
    a.set_momenta(rng.normal(size=(len(a), 3)) * 0.3)
    a.calc = SpinLatticeCalculator(terms())
    return a


def fingerprint(a):
    """Everything an error must leave untouched, bit for bit."""
    out = [(k, v.dtype.str, v.shape, v.tobytes()) for k, v in sorted(a.arrays.items())]
    out.append(("cell", a.cell.array.tobytes()))
    out.append(("pbc", a.pbc.tobytes()))
    out.append(("constraints", repr([c.todict() for c in a.constraints])))
    return out


def state(a):
    return np.concatenate([a.positions.ravel(), a.get_momenta().ravel(),
                           np.asarray(a.arrays["initial_magmoms"], float).ravel()])


def all_finite(x):
    if x is None or isinstance(x, (str, bool)):
        return True
    if isinstance(x, dict):
        return all(all_finite(v) for v in x.values())
    if isinstance(x, (list, tuple)):
        return all(all_finite(v) for v in x)
    try:
        return bool(np.isfinite(np.asarray(x, dtype=float)).all())
    except (TypeError, ValueError):
        return True


@dataclass
class Case:
    family: str
    name: str
    act: object                 # act(atoms) -> result: the library call judged, may raise
    setup: object = scene       # () -> Atoms
    prepare: object = None      # prepare(atoms): the user's edit before the call
    expect: str = "either"      # "error", "result" or "either"
    keywords: tuple = ()        # one of these must be in an error message
    check: object = None        # check(result, atoms) -> bool for results
    extra: dict = field(default_factory=dict)


def run_case(case):
    """(verdict, detail) for one case, run in this process."""
    try:
        atoms = case.setup()
        if case.prepare is not None:
            case.prepare(atoms)
    except Exception as err:  # noqa: BLE001 - a broken case, not a verdict on the library
        return "bad-error", f"setup failed: {type(err).__name__}: {err}"
    before = fingerprint(atoms) if isinstance(atoms, Atoms) else None
    try:
        result = case.act(atoms)
    except Breach as err:
        return err.verdict, str(err)[:200]
    except DOCUMENTED as err:
        message = str(err)
        if case.expect == "result":
            return "bad-error", f"unexpected {type(err).__name__}: {message[:160]}"
        if case.keywords and not any(k.lower() in message.lower() for k in case.keywords):
            return "bad-error", f"{type(err).__name__} not naming {case.keywords}: {message[:160]}"
        if before is not None and fingerprint(atoms) != before:
            return "atoms-changed", f"{type(err).__name__}: {message[:160]}"
        return "ok-error", f"{type(err).__name__}: {message[:100]}"
    except KeyboardInterrupt:
        raise
    except BaseException as err:  # noqa: BLE001 - anything else is a finding
        tb = traceback.format_exc(limit=-2).strip().splitlines()[-1]
        return "bad-error", f"{type(err).__name__}: {str(err)[:120]} ({tb[:120]})"
    if case.expect == "error":
        return "silent-wrong", f"accepted, returned {str(result)[:100]}"
    if not all_finite(result):
        return "silent-wrong", f"non-finite result {str(result)[:100]}"
    if case.check is not None:
        try:
            ok = case.check(result, atoms)
        except Exception as err:  # noqa: BLE001
            return "silent-wrong", f"check raised {type(err).__name__}: {err}"
        if not ok:
            return "silent-wrong", f"check failed, result {str(result)[:100]}"
    return "ok-result", (json.dumps(result) if isinstance(result, dict)
                         and "points" in result else "finite")


# -- the families -------------------------------------------------------------------

def _properties(atoms):
    """Everything the calculator computes."""
    calc = atoms.calc
    out = {"energy": atoms.get_potential_energy(), "forces": atoms.get_forces(),
           "B": calc.get_magnetic_forces(atoms)}
    if atoms.cell.rank == 3 and atoms.pbc.all():
        out["stress"] = atoms.get_stress()
    return out


def _run(cls=CollectivePRK, steps=2, **kw):
    def act(atoms):
        dyn = cls(atoms, kw.pop("timestep", DT), **kw)
        dyn.run(steps)
        return state(atoms)
    return act


def _both(atoms):
    """Calculator properties, then two steps of each integrator."""
    out = _properties(atoms)
    CollectivePRK(atoms, DT).run(2)
    SuzukiTrotter(atoms, DT).run(2)
    out["state"] = state(atoms)
    return out


def family_spins():
    cases = []
    rng = np.random.default_rng(11)

    def unit_ok(result, atoms):
        s = ase_spin.get_spins(atoms)
        norms = np.linalg.norm(s, axis=1)
        return bool((np.abs(norms[norms > 0] - 1.0) <= 4e-16).all())

    values = FLOAT_EDGES + WRONG_KINDS
    for k, v in enumerate(values):
        direction = [v, 0.5, 0.0] if k % 2 else [v, 0.0, 0.0]
        real = isinstance(v, float)
        finite = real and math.isfinite(v)
        expect = "result" if finite else "error"
        cases.append(Case("spins", f"direction {direction!r}",
                          lambda a, d=direction: ase_spin.set_spins(a, d),
                          expect=expect, keywords=("spin direction",), check=unit_ok))
    for v in FLOAT_EDGES + WRONG_KINDS:
        if v is None:  # the documented default: keep the magnitudes there are
            continue
        real = isinstance(v, float)
        ok = real and (v == 0.0 or 1e-100 <= v <= 1e100)
        cases.append(Case("spins", f"magnitude {v!r}",
                          lambda a, v=v: ase_spin.set_spins(a, [0, 0, 1], v),
                          expect="result" if ok else "error", keywords=("magnitude",),
                          check=unit_ok))
    for trial in range(20):  # random edge directions per atom
        d = rng.choice(np.array(FLOAT_EDGES[:14]), size=(8, 3))
        d[rng.integers(8), rng.integers(3)] = 1.0
        cases.append(Case("spins", f"random edge directions {trial}",
                          lambda a, d=d: (ase_spin.set_spins(a, d), _both(a))[1],
                          expect="either", keywords=("spin", "moment"), check=unit_ok))
    return cases


def family_moments_dtype():
    cases = []
    base = np.array([[2, 0, 2], [0, 2, 2], [1, 1, 1], [0, 0, 3]] * 2)
    for dtype in ("int8", "int16", "int32", "int64", "uint8", "float16", "float32",
                  "float64", "longdouble"):
        m = base.astype(dtype)
        mu0 = np.linalg.norm(base.astype(float), axis=1)

        def check(result, a, mu0=mu0):
            m = a.arrays["initial_magmoms"]
            return m.dtype == np.float64 and np.allclose(np.linalg.norm(m, axis=1), mu0,
                                                         rtol=1e-13, atol=0)
        cases.append(Case("moments_dtype", dtype, _both, expect="result", check=check,
                          prepare=lambda a, m=m: a.arrays.__setitem__("initial_magmoms",
                                                                      m.copy())))
    for name, m in (("complex", base.astype(complex)), ("complex 1j", base + 1j),
                    ("strings", base.astype(str)), ("bool", base.astype(bool)),
                    ("object numbers", base.astype(object)),
                    ("object strings", np.array([["1", 0, 0]] * 8, dtype=object)),
                    ("huge 1e154", base * 1e154), ("tiny 1e-160", base * 1e-160),
                    ("nan", np.where(base == 3, np.nan, base)),
                    ("collinear", np.ones(8)), ("wrong shape", np.ones((8, 2)))):
        expect = "result" if name == "object numbers" else "error"
        cases.append(Case("moments_dtype", name, _both, expect=expect,
                          keywords=("moment", "magmom"),
                          prepare=lambda a, m=m: a.arrays.__setitem__("initial_magmoms", m)))
    return cases


def family_positions():
    cases = []
    for v in [math.nan, math.inf, 1e300, 1e200, 1e12, 5e-324]:
        for pbc in (True, False):
            def prepare(a, v=v, pbc=pbc):
                a.pbc = pbc
                a.positions[3, 1] = v
            expect = "error" if not math.isfinite(v) else "either"
            cases.append(Case("positions", f"one coordinate {v!r}, pbc {pbc}", _both,
                              expect=expect, prepare=prepare,
                              keywords=("position", "too close", "moved", "overlap", "cell")))
    cases.append(Case("positions", "two atoms on top of each other", _both,
                      prepare=lambda a: a.positions.__setitem__(1, a.positions[0]),
                      expect="error", keywords=("closest pair", "overlap")))

    def same_as_float(result, a):
        b = a.copy()
        b.arrays["positions"] = b.arrays["positions"].astype(float)
        b.calc = SpinLatticeCalculator(terms())
        return abs(b.get_potential_energy() - result) <= 1e-12 * abs(result)

    for dtype in (int, np.float32):
        cases.append(Case("positions", f"{np.dtype(dtype).name} positions array",
                          lambda a: _properties(a)["energy"], expect="result",
                          check=same_as_float,
                          prepare=lambda a, dtype=dtype: a.arrays.__setitem__(
                              "positions", (np.rint(a.positions * 4) / 4 * 4).astype(dtype)
                              / 4 if dtype is not int else np.array(
                                  [[0, 0, 0], [2, 2, 0], [2, 0, 2], [0, 2, 2], [4, 0, 0],
                                   [6, 2, 0], [6, 0, 2], [4, 2, 2]]))))
    for far in (3, 1000, 1e6):
        def act(a):
            return _properties(a)["energy"]

        def check(result, a):
            b = a.copy()
            b.wrap()
            b.calc = SpinLatticeCalculator(terms())
            return abs(result - b.get_potential_energy()) <= 1e-9 * max(1.0, abs(result))
        cases.append(Case("positions", f"atoms {far} cells outside", act, expect="result",
                          check=check, prepare=lambda a, far=far: a.positions.__setitem__(
                              slice(None, None, 2),
                              a.positions[::2] + far * a.cell[0] - far * a.cell[2])))
    cases.append(Case("positions", "atom 1e12 cells outside", _both, expect="error",
                      keywords=("cell", "wrap"),
                      prepare=lambda a: a.positions.__setitem__(0, a.positions[0]
                                                                + 1e12 * a.cell[1])))
    return cases


def family_cell():
    cases = []

    def edit(fn, expect, name):
        cases.append(Case("cell", name, _both, expect=expect, keywords=("cell", "pbc"),
                          prepare=fn))

    for v in (math.nan, math.inf, -math.inf):
        edit(lambda a, v=v: a.cell.array.__setitem__((1, 2), v), "error", f"cell entry {v}")
    edit(lambda a: a.set_cell(np.zeros((3, 3))), "error", "zero cell, pbc")
    edit(lambda a: a.cell.array.__setitem__(2, 0.0), "error", "2D cell, pbc")
    edit(lambda a: a.cell.array.__setitem__(2, a.cell[0] + a.cell[1]), "error",
         "dependent vectors")
    edit(lambda a: a.set_cell(a.cell * 1e-3, scale_atoms=True), "error", "tiny cell")
    edit(lambda a: a.cell.array.__setitem__((0, 0), 1e8), "result", "1e8 Å periodic vector")
    edit(lambda a: a.cell.array.__setitem__((0, 0), 1e300), "either", "1e300 Å vector")
    edit(lambda a: a.set_cell(-a.cell.array), "result", "left-handed cell")
    edit(lambda a: (setattr(a, "pbc", False), a.positions.__setitem__(0, [5e5, 0, 0])),
         "result", "open, 5e5 Å apart")
    edit(lambda a: (setattr(a, "pbc", False), a.positions.__setitem__(0, [1e12, 0, 0])),
         "result", "open, 1e12 Å apart")
    edit(lambda a: (setattr(a, "pbc", [True, True, False]),
                    a.positions.__setitem__(0, [0, 0, 5e5])), "result", "slab, 5e5 Å apart")
    edit(lambda a: (setattr(a, "pbc", [True, False, False]),
                    a.cell.array.__setitem__((1, 1), 0.0)), "result", "wire, zero open vector")
    edit(lambda a: (setattr(a, "pbc", False), a.set_cell(np.zeros((3, 3)))), "result",
         "cluster without cell")
    return cases


def family_masses_momenta():
    cases = []
    for v in (-1.0, 0.0, math.nan, math.inf, 5e-324, 1e-300, 1e300):
        def prepare(a, v=v):
            m = a.get_masses()
            m[2] = v
            a.arrays["masses"] = m
        ok = math.isfinite(v) and v > 0
        for cls in (CollectivePRK, SuzukiTrotter):
            cases.append(Case("masses_momenta", f"mass {v!r}, {cls.__name__}", _run(cls),
                              prepare=prepare, expect="either" if ok else "error",
                              keywords=("mass", "moved", "timestep", "non-finite")))
    for v in (math.nan, math.inf, 1e200):
        for lattice in ("moving", "frozen"):
            def prepare(a, v=v):
                a.arrays["momenta"][1, 0] = v
            cases.append(Case("masses_momenta", f"momentum {v!r}, {lattice}",
                              _run(lattice=lattice), prepare=prepare,
                              expect="either" if math.isfinite(v) else "error",
                              keywords=("momenta", "moved", "timestep", "non-finite")))
    for name, value in (("masses", np.array(["1"] * 8)), ("momenta", np.ones((8, 3)) * 1j)):
        cases.append(Case("masses_momenta", f"{name} of strings/complex", _run(),
                          prepare=lambda a, name=name, value=value: a.arrays.__setitem__(
                              name, value), expect="error", keywords=(name,)))
    return cases


def family_term_params():
    cases = []
    constructors = {
        "LennardJones epsilon": lambda v: LennardJones(v, 2.27, 4.7),
        "LennardJones sigma": lambda v: LennardJones(0.4, v, 4.7),
        "LennardJones rc": lambda v: LennardJones(0.4, 2.27, v),
        "LennardJones r_on": lambda v: LennardJones(0.4, 2.27, 4.7, cutoff="smooth", r_on=v),
        "LennardJones cutoff": lambda v: LennardJones(0.4, 2.27, 4.7, cutoff=v),
        "BetheSlater J1": lambda v: BetheSlater(v, 0.0, 1.5),
        "BetheSlater J2": lambda v: BetheSlater(0.04, v, 1.5),
        "BetheSlater J3": lambda v: BetheSlater(0.04, 0.0, v),
        "Cubic J0": lambda v: Cubic(v, 3.0),
        "Cubic rc": lambda v: Cubic(0.1, v),
        "Exchange rc": lambda v: Exchange(BetheSlater(*CO_BS), rc=v),
        "Exchange offset": lambda v: Exchange(BetheSlater(*CO_BS), rc=4.0, offset=v),
        "Exchange coupling": lambda v: Exchange(v, rc=4.0),
    }
    for name, make in constructors.items():
        keyword = name.split()[-1]
        for v in FLOAT_EDGES[::2] + WRONG_KINDS + ["False", "no", 1, 0]:
            def act(a, make=make, v=v):
                term = make(v)
                if not isinstance(term, ase_spin.Term):  # a coupling
                    term = Exchange(term, rc=4.0)
                lattice = [t for t in terms() if not t.spin_dependent]
                spin = [t for t in terms() if t.spin_dependent]
                if term.spin_dependent:
                    spin = [term]
                elif isinstance(term, LennardJones):
                    lattice = [term]
                a.calc = SpinLatticeCalculator(lattice + spin)
                return _properties(a)
            cases.append(Case("term_params", f"{name} = {v!r}", act, expect="either",
                              keywords=(keyword, "coupling", "closest pair", "cell", "pair",
                                        "non-finite")))
    # assignment after construction: refused like the constructor, or takes effect
    for name, attr, v in (("epsilon", "epsilon", "x"), ("epsilon", "epsilon", math.nan),
                          ("sigma", "sigma", -1.0), ("rc", "rc", None), ("cutoff", "mode", "soft"),
                          ("epsilon", "epsilon", 0.5), ("rc", "rc", 4.0)):
        def act(a, attr=attr, v=v):
            lj = a.calc.hamiltonian.terms[0]
            setattr(lj, attr, v)
            return _properties(a)["energy"]

        def check(result, a):
            fresh = a.copy()
            fresh.calc = SpinLatticeCalculator(copy.deepcopy(list(a.calc.hamiltonian.terms)))
            return abs(result - fresh.get_potential_energy()) <= 1e-12 * abs(result)
        cases.append(Case("term_params", f"lj.{attr} = {v!r} after use", act,
                          expect="either", keywords=(name,), check=check,
                          setup=lambda: (lambda a: (a.get_potential_energy(), a)[1])(scene())))

    class Bad:
        rc = 4.0

        def __init__(self, kind):
            self.kind = kind

        def values(self, r):
            if self.kind == "nan":
                return np.full_like(r, np.nan), np.zeros_like(r)
            if self.kind == "inf derivative":
                return np.zeros_like(r), np.full_like(r, np.inf)
            if self.kind == "wrong shape":
                return np.zeros(1), np.zeros(1)
            return [0.01] * len(r), [0.0] * len(r)  # lists: fine

        def __repr__(self):
            return f"Bad({self.kind!r})"

    for kind in ("nan", "inf derivative", "wrong shape", "lists"):
        for use in ("calculator", "CollectivePRK", "SuzukiTrotter"):
            def act(a, kind=kind, use=use):
                a.calc = SpinLatticeCalculator([terms()[0], Exchange(Bad(kind))])
                if use == "calculator":
                    return _properties(a)
                cls = CollectivePRK if use == "CollectivePRK" else SuzukiTrotter
                return _run(cls)(a)
            cases.append(Case("term_params", f"user coupling {kind}, {use}", act,
                              expect="result" if kind == "lists" else "error",
                              keywords=("coupling",)))
    return cases


def family_calculator_params():
    cases = []
    for kw in (dict(skn=0.5), dict(skin=-0.1), dict(skin=math.nan), dict(skin="0.3"),
               dict(skin=math.inf), dict(skin=0.0), dict(skin=2.0), dict(txt="x")):
        key = next(iter(kw))

        def act(a, kw=kw):
            a.calc = SpinLatticeCalculator(terms(), **kw)
            return _both(a)
        ok = key == "skin" and isinstance(kw[key], float) and 0 <= kw[key] < 10
        cases.append(Case("calculator_params", repr(kw), act,
                          expect="either" if ok else "error", keywords=(key,)))
    for bad in ([], [None], ["LennardJones"], [LennardJones(**CO_LJ), 3]):
        cases.append(Case("calculator_params", f"terms {bad!r}",
                          lambda a, bad=bad: SpinLatticeCalculator(bad), expect="error",
                          keywords=("term",)))
    return cases


def family_integrator_params():
    cases = []
    settings = {
        "timestep": [0.0, -DT, math.nan, math.inf, 1j, "1", None, True, 1e-30, 1e5],
        "hbar": [0.0, -1.0, math.nan, math.inf, "1", 1j, 1e-30, 1e30],
        "tol": [0.0, -1e-15, math.nan, math.inf, 1e-2, "1e-15", 1e-300, 1e-12],
        "max_iter": [0, -1, 2.5, "10", None, True, 1, 10 ** 9],
        "order": [0, 1, 3, 8, "4", 4.0, None],
        "precession": ["Moment", "", None, 1, "spin"],
        "lattice": ["Frozen", None, ["frozen"], "frozen"],
        "composition": ["nonsense", 3, "triple_jump"],
        "append_trajectory": ["yes", 1],
        "unknown_keyword": [1],
    }
    for cls in (CollectivePRK, SuzukiTrotter):
        for key, values in settings.items():
            if cls is SuzukiTrotter and key in ("tol", "max_iter"):
                continue
            for v in values:
                def act(a, cls=cls, key=key, v=v):
                    kw = {"timestep": DT, key: v}
                    dyn = cls(a, **kw)
                    dyn.run(2)
                    return state(a)
                cases.append(Case("integrator_params", f"{cls.__name__} {key}={v!r}", act,
                                  expect="either",
                                  keywords=(key, "timestep", "spin", "moved", "rotate")))
        for v in ("exact", "Cayley", None, 1):
            if cls is SuzukiTrotter:
                cases.append(Case("integrator_params", f"rotation={v!r}",
                                  lambda a, v=v: _run(SuzukiTrotter, rotation=v)(a),
                                  expect="either", keywords=("rotation",)))
    return cases


def _mutations():
    def masses(a):
        a.set_masses(a.get_masses() * np.linspace(0.5, 2.0, len(a)))

    def term(attr, value, index=0):
        def mutate(a):
            setattr(a.calc.hamiltonian.terms[index], attr, value)
        return mutate

    def coupling(a):
        a.calc.hamiltonian.terms[1].coupling.J1 = 0.06

    def fix(a):
        a.set_constraint(FixAtoms([0, 3]))

    def fix_in_place(a):
        if a.constraints:
            a.constraints[0].index[:] = [2, 5]
        else:
            a.set_constraint(FixAtoms([1, 4]))

    def replace_fix(a):
        a.set_constraint()
        a.set_constraint(FixAtoms([6]))

    def spins(a):
        ase_spin.set_spins(a, [1, 0, 0])

    def some_non_magnetic(a):
        m = a.arrays["initial_magmoms"].copy()
        m[::3] = 0.0
        a.set_initial_magnetic_moments(m)

    def cell(a):
        a.set_cell(a.cell * 1.01, scale_atoms=True)

    def positions(a):
        a.positions[2] += [0.05, -0.02, 0.01]

    def momenta(a):
        a.set_momenta(a.get_momenta() * 1.5)

    def new_calc(a):
        a.calc = SpinLatticeCalculator(terms())

    def int_moments(a):
        a.arrays["initial_magmoms"] = np.rint(a.arrays["initial_magmoms"] * 2).astype(int)

    def float32_moments(a):
        a.arrays["initial_magmoms"] = a.arrays["initial_magmoms"].astype(np.float32)

    return {"set_masses": masses, "lj.epsilon": term("epsilon", 0.5),
            "lj.rc": term("rc", 4.2), "lj.mode": term("mode", "smooth"),
            "exchange.rc": term("rc", 3.0, 1), "exchange.offset": term("offset", True, 1),
            "coupling.J1": coupling, "FixAtoms set": fix, "FixAtoms index in place": fix_in_place,
            "FixAtoms replaced": replace_fix, "set_spins": spins,
            "some non-magnetic": some_non_magnetic, "cell": cell, "positions": positions,
            "momenta": momenta, "new calculator": new_calc, "int moments": int_moments,
            "float32 moments": float32_moments}


def family_mutations(orders=(2,)):
    cases = []
    for cls in (CollectivePRK, SuzukiTrotter):
        for order in orders:
            for name, mutate in _mutations().items():
                def act(a, cls=cls, order=order, mutate=mutate, name=name):
                    if "in place" in name:
                        a.set_constraint(FixAtoms([1, 4]))
                    dyn = cls(a, DT, order=order)
                    dyn.run(3)
                    mutate(a)
                    dyn.run(3)
                    return state(a), dyn.get_potential_energy()

                def check(result, a, cls=cls, order=order, mutate=mutate, name=name):
                    b = scene()
                    if "in place" in name:
                        b.set_constraint(FixAtoms([1, 4]))
                    cls(b, DT, order=order).run(3)
                    mutate(b)
                    fresh = b.copy()
                    fresh.calc = SpinLatticeCalculator(
                        copy.deepcopy(list(b.calc.hamiltonian.terms)))
                    fresh.set_constraint(copy.deepcopy(b.constraints))
                    d = cls(fresh, DT, order=order)
                    d.run(3)
                    s, e = result
                    return (np.abs(s - state(fresh)).max() <= 1e-10
                            and abs(e - d.get_potential_energy()) <= 1e-10 * max(1, abs(e)))
                cases.append(Case("mutations", f"{cls.__name__} order {order}: {name}", act,
                                  expect="result", check=check))

        def shared(a, cls=cls):
            b = scene(1)
            b.calc = a.calc
            d1, d2 = cls(a, DT), cls(b, DT)
            d1.run(3)
            d2.run(3)
            b.get_potential_energy()
            d1.run(3)
            return state(a)

        def shared_check(result, a, cls=cls):
            ref = scene()
            cls(ref, DT).run(6)
            return np.abs(result - state(ref)).max() <= 1e-12
        cases.append(Case("mutations", f"{cls.__name__}: calculator shared by two Atoms",
                          shared, expect="result", check=shared_check))

        def copy_other_magnetic(a, cls=cls):
            d = cls(a, DT)
            d.run(2)
            c = a.copy()
            m = c.arrays["initial_magmoms"].copy()
            m[1::2] = 0.0
            c.set_initial_magnetic_moments(m)
            c.calc = a.calc
            cls(c, DT).run(2)
            d.run(2)
            return state(a), state(c)
        cases.append(Case("mutations", f"{cls.__name__}: copy with other magnetic atoms",
                          copy_other_magnetic, expect="result"))
    return cases


def family_interrupts(stride=1, combos=None):
    """One case per (integrator, order, constraint): a KeyboardInterrupt at
    every ``stride``-th line executed in ase_spin during a step."""
    combos = combos or [(CollectivePRK, 2, False), (CollectivePRK, 4, True),
                        (SuzukiTrotter, 2, True), (SuzukiTrotter, 4, False)]
    cases = []
    for cls, order, constrained in combos:
        def act(a, cls=cls, order=order, constrained=constrained):
            return interrupt_campaign(cls, order, constrained, stride)

        def check(result, a):
            return result["mixed"] == 0 and result["worst"] <= 1e-12 and result["points"] > 0
        cases.append(Case("interrupts", f"{cls.__name__} order {order}"
                          f"{' FixAtoms' if constrained else ''} every {stride}", act,
                          expect="result", check=check))
    return cases


def interrupt_campaign(cls, order, constrained, stride=1):
    def make():
        a = scene()
        if constrained:
            a.set_constraint(FixAtoms([0]))
        return cls(a, DT, order=order)
    return interrupted_runs(make, lambda dyn: (state(dyn.atoms),), stride)


def interrupted_runs(make, look, stride=1):
    """A KeyboardInterrupt at every ``stride``-th line executed in ase_spin
    during the third step of a run made by ``make()``, then running on to
    step 5. ``look(dyn)`` -> (array, *exact): what must be all before or all
    after the step (the array to the bit, the rest equal), and the array the
    continued run must reach. ``mixed`` counts points that were neither;
    ``worst`` the largest difference of the array from the uninterrupted run."""
    ref = make()
    ref.run(2)
    marks = {2: look(ref)}
    ref.run(1)
    marks[3] = look(ref)
    ref.run(2)
    final = look(ref)[0]
    k = points = mixed = 0
    worst = 0.0
    while True:
        k += stride
        dyn = make()
        dyn.run(2)
        if interrupted_at(k, lambda: dyn.run(1)):
            break
        points += 1
        now, at = look(dyn), marks.get(dyn.nsteps)
        if at is None or not np.array_equal(now[0], at[0]) or now[1:] != at[1:]:
            mixed += 1
            continue
        dyn.run(5 - dyn.nsteps)
        worst = max(worst, float(np.abs(look(dyn)[0] - final).max()))
    return {"points": points, "mixed": mixed, "worst": worst}


LANGEVIN = dict(temperature_K=400.0, spin_damping=0.2, friction=0.01 / units.fs)


def _langevin(a, rng=11, **kw):
    return ase_spin.Langevin(a, 2.5 * DT, **{**LANGEVIN, "rng": rng, **kw})


def _unit_state(a):
    """positions, momenta and unit spins (the midpoint solve's tolerance is on
    unit spins)."""
    m = np.asarray(a.arrays["initial_magmoms"], float)
    return np.concatenate([a.positions.ravel(), a.get_momenta().ravel(),
                           (m / np.linalg.norm(m, axis=1, keepdims=True)).ravel()])


def langevin_interrupt_campaign(extra, stride=1):
    """:func:`interrupted_runs` of a Langevin run (exchange alone, or with a
    field and an anisotropy): the Atoms, nsteps, the generator and the bath
    energy all before or all after the step; ``worst`` over positions,
    momenta, unit spins and the bath energy."""
    def make():
        a = scene()
        if extra:
            a.calc = SpinLatticeCalculator(terms() + [ase_spin.Zeeman(5.0, [0, 0, 1]),
                                                      ase_spin.UniaxialAnisotropy(1e-3, [1, 0, 0])])
        return _langevin(a)

    def look(dyn):
        return (np.append(_unit_state(dyn.atoms), dyn.get_bath_energy()),
                dyn.rng.bit_generator.state)
    return interrupted_runs(make, look, stride)


def family_langevin(stride=1):
    """The thermostat: interrupts anywhere in a step, bath parameters changed
    between runs (the run must go on as a new Langevin with them from the same
    Atoms and generator), parameters set to impossible values as attributes
    or given out of range."""
    cases = []
    for extra in (False, True):
        def act(a, extra=extra):
            return langevin_interrupt_campaign(extra, stride)

        def check(result, a):
            return result["mixed"] == 0 and result["points"] > 0 and result["worst"] <= 1e-9
        cases.append(Case("langevin", f"interrupts{' field+anisotropy' if extra else ''} "
                          f"every {stride}", act, expect="result", check=check))

    changes = {"spin_damping": ("spin_damping", 0.6), "friction": ("fr", 0.05 / units.fs),
               "temperature": ("temp", 900.0 * units.kB),
               "spin temperature": ("spin_temp", 50.0 * units.kB), "timestep": ("dt", 0.3 * DT)}
    for name, (attr, value) in changes.items():
        def act(a, attr=attr, value=value):
            dyn = _langevin(a)
            dyn.run(3)
            setattr(dyn, attr, value)
            rng_state = dyn.rng.bit_generator.state
            copy_ = a.copy()
            copy_.calc = SpinLatticeCalculator(copy.deepcopy(list(a.calc.hamiltonian.terms)))
            dyn.run(3)
            rng = np.random.default_rng()
            rng.bit_generator.state = rng_state
            kw = {"spin_damping": dyn.spin_damping, "friction": dyn.fr,
                  "temperature_K": dyn.temp / units.kB,
                  "spin_temperature_K": dyn.spin_temp / units.kB}
            fresh = ase_spin.Langevin(copy_, dyn.dt, rng=rng, **kw)
            fresh.run(3)
            return float(np.abs(_unit_state(a) - _unit_state(copy_)).max())

        cases.append(Case("langevin", f"{name} changed between runs", act, expect="result",
                          check=lambda result, a: result <= 1e-9))

    for attr in ("spin_damping", "fr", "temp", "spin_temp"):
        for v in (math.nan, math.inf, -1.0, -0.0 - 1e-300, 1e300, "1", None):
            def act(a, attr=attr, v=v):
                dyn = _langevin(a)
                setattr(dyn, attr, v)
                dyn.run(1)
                return state(a)
            # (a friction of 1e300 is the overdamped limit: momenta redrawn each step)
            cases.append(Case("langevin", f"dyn.{attr} = {v!r}", act,
                              expect="either" if (attr, v) == ("fr", 1e300) else "error",
                              keywords=("spin_damping", "friction", "temp", "real number")))
    for key in ("temperature_K", "spin_temperature_K", "spin_damping", "friction"):
        for v in (math.nan, -1.0, 1e300, 1e30, "300", True):
            def act(a, key=key, v=v):
                dyn = _langevin(a, **{key: v})
                dyn.run(2)
                return state(a)
            cases.append(Case("langevin", f"Langevin({key}={v!r})", act, expect="either",
                              keywords=(key,)))
    return cases


def family_files(stride=1):
    from ase.io import read

    cases = []

    tmp = Path(tempfile.mkdtemp(prefix="fuzz-files-"))

    def written(a):
        path = tmp / "md.traj"
        path.unlink(missing_ok=True)
        CollectivePRK(a, DT, trajectory=str(path)).run(2)

    def exists(a):
        path = tmp / "md.traj"
        data = path.read_bytes()
        try:
            CollectivePRK(a, DT, trajectory=str(path))
        finally:
            assert path.read_bytes() == data, "trajectory modified"
    cases.append(Case("files", "existing trajectory", exists, expect="error",
                      keywords=("append_trajectory",), prepare=written))

    def truncated(a):
        from ase_spin.io.trajectories import recover_trajectory

        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "md.traj"
            CollectivePRK(a, DT, trajectory=str(path)).run(3)
            frames = read(path, ":")
            data = path.read_bytes()
            bad = 0
            for cut in range(len(data) - 1500, len(data), stride):
                cut_path = Path(tmp) / "cut.traj"
                cut_path.write_bytes(data[:cut])
                n = recover_trajectory(cut_path, Path(tmp) / "rec.traj", overwrite=True)
                got = read(Path(tmp) / "rec.traj", ":")
                if n != len(got) or n > len(frames) or n < len(frames) - 2 or any(
                        not np.array_equal(x.positions, y.positions) for x, y in zip(got, frames)):
                    bad += 1
            return bad
    cases.append(Case("files", f"truncated trajectory, every {stride} bytes", truncated,
                      expect="result", check=lambda bad, a: bad == 0))

    def append_truncated(a):
        path = tmp / "cut.traj"
        path.unlink(missing_ok=True)
        CollectivePRK(scene(), DT, trajectory=str(path)).run(2)
        path.write_bytes(path.read_bytes()[:-50])
        CollectivePRK(a, DT, trajectory=str(path), append_trajectory=True).run(1)
    cases.append(Case("files", "append to a truncated trajectory", append_truncated,
                      expect="error", keywords=("recover",)))
    return cases


def family_systems():
    cases = []
    for lattice in ("moving", "frozen"):
        for cls in (CollectivePRK, SuzukiTrotter):
            def empty(a, cls=cls, lattice=lattice):
                e = Atoms()
                e.calc = SpinLatticeCalculator(terms())
                cls(e, DT, lattice=lattice).run(2)
                return e.get_potential_energy()
            cases.append(Case("systems", f"empty, {cls.__name__} {lattice}", empty,
                              expect="result"))

            def one(a, cls=cls, lattice=lattice):
                b = a[:1]
                b.calc = SpinLatticeCalculator(terms())
                cls(b, DT, lattice=lattice).run(2)
                return _properties(b)
            cases.append(Case("systems", f"one atom, {cls.__name__} {lattice}", one,
                              expect="result"))

            def run(a, cls=cls, lattice=lattice):
                cls(a, DT, lattice=lattice).run(2)
                return _properties(a)
            cases.append(Case("systems", f"non-magnetic, {cls.__name__} {lattice}", run,
                              expect="result",
                              prepare=lambda a: ase_spin.set_spins(a, np.zeros((len(a), 3)))))
            cases.append(Case("systems", f"all fixed, {cls.__name__} {lattice}", run,
                              expect="result",
                              prepare=lambda a: a.set_constraint(FixAtoms(range(len(a))))))
    return cases


# -- security: data must not run code, write elsewhere, or destroy files ---------------

SECURITY_SCENE = """
[structure]
build = {function = "bulk", name = "Co", crystalstructure = "fcc", a = 3.54, cubic = true}

[spins]
magnitude = 1.72

[[terms]]
type = "Exchange"
coupling = {type = "BetheSlater", J1 = 0.0446928, J2 = 0.003496, J3 = 1.4885}
rc = 4.0

[integrator]
timestep = 0.5
steps = 1

[output]
trajectory = "md.traj"
log = "md.log"
"""


def _folder_state(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def _cli_case(name, changes, keywords, verdict, overwrite=True, prepare_folder=None):
    """A case running ``ase-spin run`` on the scene changed by ``changes``
    ((old, new) pairs) in a fresh folder: an input error is expected, and the
    folder must hold exactly what it held (else ``verdict``)."""
    def act(atoms):
        folder = Path(tempfile.mkdtemp(prefix="fuzz-security-"))
        text = SECURITY_SCENE
        for old, new in changes:
            assert old in text, old
            text = text.replace(old, new, 1)
        (folder / "scene.toml").write_text(text)
        if prepare_folder is not None:
            prepare_folder(folder)
        before = _folder_state(folder)
        try:
            return cli.run(folder / "scene.toml", overwrite=overwrite, progress=False,
                           out=open(os.devnull, "w"))
        finally:
            after = _folder_state(folder)
            if after != before:
                changed = sorted(set(after) ^ set(before) | {k for k in before if k in after
                                                             and after[k] != before[k]})
                raise Breach(verdict, f"files changed: {changed}")
    return Case("security", name, act, expect="error", keywords=keywords)


def family_security():
    from ase.calculators.emt import EMT

    cases = []
    tmp = Path(tempfile.mkdtemp(prefix="fuzz-security-"))

    def from_dict(data, allow=None):
        def act(atoms):
            marker = tmp / "imported"
            try:
                calc = (SpinLatticeCalculator.from_dict(data) if allow is None
                        else SpinLatticeCalculator.from_dict(data, allow=allow))
            finally:
                if marker.exists():
                    raise Breach("security", "a module named in the data was imported")
            built = [t for t in calc.hamiltonian.terms if hasattr(t, "calculator")]
            if built:
                raise Breach("security", f"built {type(built[0].calculator).__name__} from "
                                          "data")
            return calc.todict()
        return act

    (tmp / "fuzz_evil_module.py").write_text(
        f"open({str(tmp / 'imported')!r}, 'w').write('ran')\nclass Term:\n    pass\n")
    sys.path.insert(0, str(tmp))
    for path in ("fuzz_evil_module:Term", "os:system", "builtins:eval", "ase_spin.app.cli:main"):
        cases.append(Case("security", f"from_dict of the class {path}",
                          from_dict({"terms": [{"__class__": path, "args": {}}]}),
                          expect="error", keywords=("refused to build", path)))
    lammps = {"__class__": "ase_spin.terms.ase_calculator:CalculatorTerm",
              "args": {"calculator": {"__calculator__": "ase.calculators.lammpsrun:LAMMPS",
                                      "parameters": {"command": "touch pwned"}}}}
    cases.append(Case("security", "from_dict of ASE's LAMMPS calculator with a command",
                      from_dict({"terms": [lammps]}), expect="error",
                      keywords=("refused to build the ASE calculator",)))
    emt = json.loads(json.dumps(SpinLatticeCalculator([EMT()]).todict()))
    cases.append(Case("security", "from_dict of EMT, not allowed", from_dict(emt),
                      expect="error", keywords=("allow=[EMT]",)))
    cases.append(Case("security", "from_dict of EMT, allowed by another class",
                      from_dict(emt, allow=[LennardJones]), expect="error",
                      keywords=("allow=[EMT]",)))

    def deck(**names):
        def act(atoms):
            folder = tmp / f"deck{len(list(tmp.iterdir()))}"
            before = _folder_state(tmp)
            try:
                return ase_spin.write_lammps(folder / "run", atoms, timestep=DT, **names)
            finally:
                after = _folder_state(tmp)
                if after != before or folder.exists():
                    raise Breach("security", f"wrote {sorted(set(after) - set(before))}")
        return act

    def lammps_scene():
        a = scene()
        a.calc = SpinLatticeCalculator(terms(), conventions="lammps")
        return a

    for key, name in (("input_name", "in.spin\nshell touch pwned"),
                      ("dump_name", "dump.spin\rshell rm -rf ~"),
                      ("energy_name", "e.spin & shell touch pwned"),
                      ("data_name", "../../escaped.data"),
                      ("data_name", str(tmp / "escaped.data")),
                      ("data_name", ".."),
                      ("dump_name", "${pwned}"),
                      ("input_name", "in.spin#"),
                      ("dump_name", "dump.*"),
                      ("data_name", "in.spin")):
        cases.append(Case("security", f"deck {key} {name!r}", deck(**{key: name}),
                          setup=lammps_scene, expect="error", keywords=(key,)))

    logger = ('rc = {type = "SpinMDLogger", dyn = {type = "Cubic", J0 = 0.1, rc = 3.0}, '
              'logfile = "pwned.txt"}')
    cases.append(_cli_case("input: a logger nested in a term", [("rc = 4.0", logger)],
                           ("builds a coupling",), "security"))
    coupling = 'coupling = {type = "BetheSlater", J1 = 0.0446928, J2 = 0.003496, J3 = 1.4885}'
    calculator = 'coupling = {"Co-Co" = {type = "SpinLatticeCalculator", terms = []}}'
    cases.append(_cli_case("input: a calculator nested in a term", [(coupling, calculator)],
                           ("builds a coupling",), "security"))
    composition = 'steps = 1\ncomposition = {type = "Cubic", J0 = 0.1, rc = 3.0}'
    cases.append(_cli_case("input: a coupling nested in the integrator",
                           [("steps = 1", composition)], ("builds a coupling",), "security"))
    cases.append(_cli_case("input: trajectory = the input file, overwrite",
                           [('trajectory = "md.traj"', 'trajectory = "scene.toml"')],
                           ("the input file",), "data-loss"))
    build = ('build = {function = "bulk", name = "Co", crystalstructure = "fcc", a = 3.54, '
             'cubic = true}')
    cases.append(_cli_case("input: log = the structure file, overwrite",
                           [(build, 'file = "start.xyz"'), ('log = "md.log"', 'log = "start.xyz"')],
                           ("structure file",), "data-loss",
                           prepare_folder=lambda f: _write_structure(f / "start.xyz")))
    cases.append(_cli_case("input: log = trajectory", [('log = "md.log"', 'log = "md.traj"')],
                           ("interleaved",), "data-loss"))
    cases.append(_cli_case("input: outputs of a run in progress, overwrite", [],
                           ("being written",), "data-loss",
                           prepare_folder=lambda f: _run_in_progress(f, cli.LOCK_SUFFIX)))
    cases.append(_cli_case("input: direction = [0, 0, true]",
                           [("magnitude = 1.72", "magnitude = 1.72\ndirection = [0, 0, true]")],
                           ("direction",), "silent-wrong"))
    return cases


def _write_structure(path):
    from ase.io import write

    write(path, bulk("Co", "fcc", a=3.54, cubic=True))


def _run_in_progress(folder, suffix):
    """md.traj and md.log of another run on this machine that is writing them."""
    import socket

    (folder / "md.traj").write_bytes(b"frames of another run")
    (folder / "md.log").write_text("Time[ps]\n")
    (folder / f"md.traj{suffix}").write_text(f"{os.getppid()} {socket.gethostname()}\n")
# -- input data: symmetry, potential files, LAMMPS files, TB2J, ASE calculators ------

_TMP = []


def _tmp():
    """A folder for the files the cases write (one per process)."""
    if not _TMP:
        _TMP.append(Path(tempfile.mkdtemp(prefix="fuzz-input-")))
    return _TMP[0]


def _names(path, act):
    """``act()``, with a documented error that does not name the file turned
    into a finding (a RuntimeError: bad-error)."""
    try:
        return act()
    except DOCUMENTED as err:
        if Path(path).name not in str(err):
            raise RuntimeError(f"the error does not name the file: {err}") from None
        raise


def _crystal():
    a = bulk("Fe", "bcc", a=2.87, cubic=True)
    ase_spin.set_spins(a, [[0, 0, 1], [0, 0, 1]], 2.2)
    return a


def family_symmetry(quick=False):
    from ase_spin import magnetic_symmetry, neighbor_shells

    cases = []
    calls = {"neighbor_shells": lambda a: neighbor_shells(a, 4.2).multiplicities(),
             "magnetic_symmetry": lambda a: magnetic_symmetry(a).bns_number}
    expected = {"neighbor_shells": [8, 6, 12], "magnetic_symmetry": "139.537"}
    edits = {
        "NaN position": lambda a: a.positions.__setitem__((1, 0), math.nan),
        "inf position": lambda a: a.positions.__setitem__((0, 2), -math.inf),
        "NaN cell": lambda a: a.cell.array.__setitem__((0, 0), math.nan),
        "inf cell": lambda a: a.cell.array.__setitem__((2, 1), math.inf),
        "position 1e18": lambda a: a.positions.__setitem__(1, a.positions[1] + 1e18),
        "atom 3e7 cells away": lambda a: a.positions.__setitem__(0, a.positions[0]
                                                                 + 3e7 * a.cell[0]),
    }
    for fname, call in calls.items():
        for name, edit in edits.items():
            if quick and "inf" in name:
                continue
            cases.append(Case("symmetry", f"{fname}: {name}", call, setup=_crystal, prepare=edit,
                              expect="error", keywords=("position", "cell", "wrap")))
        for far in (0, 1000) if not quick else (1000,):
            cases.append(Case(
                "symmetry", f"{fname}: atom {far} cells away", call, setup=_crystal,
                prepare=lambda a, far=far: a.positions.__setitem__(
                    1, a.positions[1] + far * a.cell[0] - 7 * a.cell[2]),
                expect="result", check=lambda r, a, want=expected[fname]: r == want))
    for rmax in (1e4, 1e300, 70.0) if not quick else (1e4,):
        cases.append(Case("symmetry", f"neighbor_shells rmax = {rmax:g}",
                          lambda a, rmax=rmax: neighbor_shells(a, rmax), setup=_crystal,
                          expect="error", keywords=("rmax",)))
    return cases


def _setfl_text(nrho=20, nr=20, dr=0.3, drho=0.1, elements=("Fe", "Co")):
    """A small setfl file of smooth functions (as tests/test_eam.py writes)."""
    r = np.arange(nr) * dr
    rho = np.arange(nrho) * drho
    lines = ["DATE: today UNITS: metal", "fuzz potential", "#",
             f"{len(elements)} " + " ".join(elements), f"{nrho} {drho!r} {nr} {dr!r} 5.7"]

    def block(values):
        return [" ".join(repr(float(v)) for v in values[k:k + 5])
                for k in range(0, len(values), 5)]

    for k, _ in enumerate(elements):
        lines.append(f"{26 + k} 55.845 2.855 bcc")
        lines += block(-np.sqrt(rho) * (1 + 0.1 * k))
        lines += block(np.exp(-r) * (1 + 0.2 * k) * (5.7 - r) ** 2)
    for a in range(len(elements)):
        for b in range(a + 1):
            lines += block(r * (np.exp(-2 * r) * 10 - 0.1 * np.exp(-r)) * (5.7 - r) ** 2)
    return "\n".join(lines) + "\n"


def _eam_energy(text, name):
    from ase_spin import EAM

    def act(a):
        path = _tmp() / f"{name}.eam.alloy"
        path.write_text(text)
        term = _names(path, lambda: EAM(path))
        b = bulk("Fe", "bcc", a=2.87, cubic=True).repeat(2)
        b.symbols[::3] = "Co"
        ase_spin.set_spins(b, [0, 0, 1], 2.2)
        b.calc = SpinLatticeCalculator([term])
        return b.get_potential_energy()
    return act


def family_eam_files(quick=False):
    cases = []
    good = _setfl_text()
    header = "20 0.1 20 0.3 5.7"
    reference = []

    def same(result, a):
        if not reference:
            reference.append(_eam_energy(good, "reference")(a))
        return result == reference[0]
    cases.append(Case("eam_files", "good file", _eam_energy(good, "good"), expect="result",
                      check=same))
    steps = ["1e-20", "1e-9", "5e-324", "0", "-0.3", "nan", "inf"]
    for v in steps[:3] if quick else steps:
        cases.append(Case("eam_files", f"dr = {v}",
                          _eam_energy(good.replace(header, f"20 0.1 20 {v} 5.7"), f"dr{v}"),
                          expect="error", keywords=("dr",)))
        cases.append(Case("eam_files", f"drho = {v}",
                          _eam_energy(good.replace(header, f"20 {v} 20 0.3 5.7"), f"drho{v}"),
                          expect="result" if v in ("1e-20", "1e-9") else "error",
                          keywords=("drho",), check=lambda r, a: math.isfinite(r)))
    counts = {"Nrho 15 (smaller)": "15 0.1 20 0.3 5.7", "Nr 15 (smaller)": "20 0.1 15 0.3 5.7",
              "Nrho 19": "19 0.1 20 0.3 5.7", "Nr 25 (larger)": "20 0.1 25 0.3 5.7",
              "Nr 1e12": "20 0.1 1000000000000 0.3 5.7",
              "Nrho 1e23": "100000000000000000000000 0.1 20 0.3 5.7"}
    for k, (name, line) in enumerate(counts.items()):
        if quick and k % 2:
            continue
        cases.append(Case("eam_files", f"header {name}",
                          _eam_energy(good.replace(header, line), f"count{k}"), expect="error",
                          keywords=("value", "count", "truncated", "not a number")))
    one = _setfl_text(elements=("Fe",))
    for name, text in (("trailing values", good + "1.0 2.0\n"),
                       ("one element, Nr 15", one.replace(header, "20 0.1 15 0.3 5.7")),
                       ("one element, trailing line", one + "0.5 0.5 0.5 0.5 0.5\n")):
        cases.append(Case("eam_files", name, _eam_energy(text, name.replace(" ", "_")),
                          expect="error", keywords=("after the last block",)))
    return cases


_DUMP_FRAME = ("ITEM: TIMESTEP\n{step}\nITEM: NUMBER OF ATOMS\n{n}\n"
               "ITEM: BOX BOUNDS pp pp pp\n0.0 10.0\n0.0 8.0\n0.0 6.0\n"
               "ITEM: ATOMS {columns}\n{rows}")
_DUMP_COLUMNS = "id type x y z sp spx spy spz"
_DUMP_ROWS = "2 1 1.25 2 3 2.0 0 0 1\n1 2 4 5 6.5 1.5 1 0 0\n"


def _dump(step=0, n=2, columns=_DUMP_COLUMNS, rows=_DUMP_ROWS):
    return _DUMP_FRAME.format(step=step, n=n, columns=columns, rows=rows)


def _read_dump(text, name):
    from ase_spin.interop.lammps_dump import read_lammps_spin_dump

    def act(a):
        path = _tmp() / f"{name}.dump"
        path.write_text(text)
        return _names(path, lambda: read_lammps_spin_dump(path, symbols=["Fe", "Co"]))
    return act


def _frames_of(result, steps):
    """A list of frames: a prefix of the whole dump's, each exactly right."""
    return (isinstance(result, list) and 1 <= len(result) <= len(steps) and all(
        f.info["timestep"] == s and np.array_equal(f.positions, [[4, 5, 6.5], [1.25, 2, 3]])
        and np.array_equal(f.get_initial_magnetic_moments(), [[1.5, 0, 0], [0, 0, 2.0]])
        for f, s in zip(result, steps)))


def family_lammps_files(quick=False):
    from ase_spin.interop.lammps import write_lammps

    cases = []
    whole = _dump(0) + _dump(10) + _dump(20)
    last = whole.index("ITEM: TIMESTEP\n20")
    for cut in range(last - 3, len(whole) + 1, 17 if quick else 1):
        cases.append(Case("lammps_files", f"dump cut at byte {cut} of {len(whole)}",
                          _read_dump(whole[:cut], f"cut{cut}"), expect="either",
                          keywords=("cut short",),
                          check=lambda r, a: _frames_of(r, [0, 10, 20])))
    bad = {
        "atom count too large": _dump(0, n=3) + _dump(10),
        "no id column": _dump(0, columns=_DUMP_COLUMNS.replace("id ", "ID ")),
        "no type column": _dump(0, columns=_DUMP_COLUMNS.replace("type ", "kind ")),
        "scaled positions only": _dump(0, columns=_DUMP_COLUMNS.replace("x y z", "xs ys zs")),
        "duplicate id": _dump(0, rows=_DUMP_ROWS.replace("2 1 1.25", "1 1 1.25")),
        "fractional type": _dump(0, rows=_DUMP_ROWS.replace("2 1 1.25", "2 1.5 1.25")),
        "NaN position": _dump(0, rows=_DUMP_ROWS.replace("4 5 6.5", "nan 5 6.5")),
        "inf box": _dump(0).replace("0.0 8.0", "0.0 inf"),
        "short row": _dump(0, rows=_DUMP_ROWS.replace("4 5 6.5", "4 5")) + _dump(10),
        "word in a row": _dump(0, rows=_DUMP_ROWS.replace("4 5 6.5", "4 x 6.5")),
        "fractional timestep": _dump("1.5"),
        "binary": "\0\1\2ITEM",
        "empty": "",
    }
    for k, (name, text) in enumerate(bad.items()):
        if quick and k % 3:
            continue
        cases.append(Case("lammps_files", f"dump: {name}", _read_dump(text, f"bad{k}"),
                          expect="error", keywords=("line", "frame", "text", "column")))

    def write(**kw):
        def act(a):
            return write_lammps(_tmp() / "deck", a, **{"timestep": DT, **kw}).input.name
        return act
    edits = {
        "NaN position": (lambda a: a.positions.__setitem__((1, 1), math.nan), {}, "positions"),
        "inf velocity": (lambda a: a.arrays["momenta"].__setitem__((2, 0), math.inf), {},
                         "velocities"),
        "NaN timestep": (None, {"timestep": math.nan}, "timestep"),
        "steps 2.5": (None, {"steps": 2.5}, "steps"),
        "steps -1": (None, {"steps": -1}, "steps"),
        "dump_interval 0.5": (None, {"dump_interval": 0.5}, "dump_interval"),
    }
    for k, (name, (prepare, kw, keyword)) in enumerate(edits.items()):
        if quick and k % 2:
            continue
        cases.append(Case("lammps_files", f"write_lammps: {name}", write(**kw), prepare=prepare,
                          expect="error", keywords=(keyword,)))
    cases.append(Case("lammps_files", "write_lammps: good", write(steps=3), expect="result",
                      check=lambda r, a: r == "in.spin"))
    return cases


def _tb2j_text():
    return (HERE / "data" / "tb2j_bcc_Fe" / "exchange.out").read_text()


def _read_tb2j(text, name):
    from ase_spin import read_tb2j

    def act(a):
        path = _tmp() / f"{name}.out"
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
        t = _names(path, lambda: read_tb2j(path))
        return [(int(i), int(j), tuple(int(x) for x in R), float(J))
                for i, j, R, J in zip(t.i, t.j, t.R, t.J)]
    return act


def family_tb2j(quick=False):
    cases = []
    text = _tb2j_text()
    full = []

    def subset(result, a):
        if not full:
            full.extend(_read_tb2j(text, "full")(a))
        return len(result) > 0 and set(result) <= set(full)
    start = text.index("Exchange:")
    for cut in range(start - 40, len(text) + 1, 401 if quick else 7):
        cases.append(Case("tb2j", f"cut at byte {cut} of {len(text)}",
                          _read_tb2j(text[:cut], f"cut{cut}"), expect="either",
                          keywords=("line", "section", "pair", "atom"), check=subset))
    bad = {
        "pair line cut inside": text.replace("(-1.415, -1.415, -1.415)  2.451", "(-1.4", 1),
        "wrong distance": text.replace("(-1.415, -1.415, -1.415)  2.451",
                                       "(-1.415, -1.415, -1.415)  2.1", 1),
        "NaN moment": text.replace("2.5763", "nan", 1),
        "inf J": text.replace("19.6502   (-1.415", "inf   (-1.415", 1),
        "NaN cell": text.replace("2.83000000  0.00000000", "nan  0.00000000", 1),
        "unknown element": text.replace("Fe1 ", "Xq1 ").replace("Fe1)", "Xq1)"),
        "huge R": text.replace("( -1,  -1,  -1)", "(-99999999999999999999, -1, -1)", 1),
        "NUL bytes": text.replace("Exchange:", "Exchange:\0\1", 1),
        "not UTF-8": text.replace("Exchange:", "Exchange: \xff", 1).encode("latin-1"),
    }
    for k, (name, bad_text) in enumerate(bad.items()):
        if quick and k % 2:
            continue
        cases.append(Case("tb2j", name, _read_tb2j(bad_text, f"bad{k}"), expect="error",
                          keywords=("line", "text file")))
    return cases


def family_ase_calculators(quick=False):
    from ase.calculators.calculator import Calculator, all_changes

    class Springs(Calculator):
        implemented_properties = ("energy", "forces")

        def __init__(self, bad=None, delay=0.0):
            super().__init__()
            self.bad, self.delay = bad, delay

        def calculate(self, atoms=None, properties=("energy",), system_changes=all_changes):
            import time

            super().calculate(atoms, properties, system_changes)
            time.sleep(self.delay)
            x = self.atoms.positions
            self.results = {"energy": 0.5 * (x ** 2).sum(), "forces": -x.copy()}
            if self.bad == "forces of one atom":
                self.results["forces"] = -x[:1].copy()
            elif self.bad == "forces (3,)":
                self.results["forces"] = np.ones(3)
            elif self.bad == "forces transposed":
                self.results["forces"] = -x.T.copy()
            elif self.bad == "string energy":
                self.results["energy"] = "1.5"
            elif self.bad == "complex energy":
                self.results["energy"] = 1.5 + 0j
            elif self.bad == "None energy":
                self.results["energy"] = None
            elif self.bad == "changes the cell":
                atoms.set_cell(atoms.cell.array * 1.5, scale_atoms=True)
            elif self.bad == "changes pbc":
                atoms.pbc = False

    def with_calculator(bad):
        def act(a):
            a.calc = SpinLatticeCalculator([Springs(bad), terms()[1]])
            return {"energy": a.get_potential_energy(), "forces": a.get_forces()}
        return act

    cases = []
    kinds = ["forces of one atom", "forces (3,)", "forces transposed", "string energy",
             "complex energy", "None energy", "changes the cell", "changes pbc"]
    for k, bad in enumerate(kinds):
        if quick and k % 2:
            continue
        cases.append(Case("ase_calculators", bad, with_calculator(bad), expect="error",
                          keywords=("springs",)))

    def springs_and_exchange(result, a):
        b = a.copy()
        b.calc = SpinLatticeCalculator([terms()[1]])
        return np.allclose(result["forces"], b.get_forces() - a.positions, rtol=0, atol=1e-12)
    cases.append(Case("ase_calculators", "good", with_calculator(None), expect="result",
                      check=springs_and_exchange))

    def threads(a):
        import threading

        shared = Springs(delay=0.001)
        scenes = [scene(seed) for seed in (1, 2)]
        for b in scenes:
            b.calc = SpinLatticeCalculator([shared, terms()[1]])
        wrong = []

        def work(b):
            for k in range(10):
                b.positions[0, 0] += 1e-3  # a new state: a new calculation
                f = b.get_forces()
                alone = b.copy()  # the same with a calculator of its own
                alone.calc = SpinLatticeCalculator([Springs(), terms()[1]])
                if not np.array_equal(f, alone.get_forces()):
                    wrong.append(k)
        workers = [threading.Thread(target=work, args=(b,)) for b in scenes]
        for w in workers:
            w.start()
        for w in workers:
            w.join()
        return len(wrong)
    cases.append(Case("ase_calculators", "one calculator, two threads", threads,
                      expect="result", check=lambda wrong, a: wrong == 0))
    return cases


CLI_SCENE = """
[structure]
build = {function = "bulk", name = "Co", crystalstructure = "fcc", a = 3.54, cubic = true}
repeat = [1, 1, 2]
rattle = 0.01

[spins]
magnitude = 1.72
cone = 20

[velocities]
temperature = 100

[[terms]]
type = "LennardJones"
epsilon = 0.4
sigma = 2.2742
rc = 4.7

[[terms]]
type = "Exchange"
coupling = {type = "BetheSlater", J1 = 0.0446928, J2 = 0.003496, J3 = 1.4885}
rc = 4.0

[[terms]]
type = "Zeeman"
field = [0, 0, 2]

[integrator]
type = "Langevin"
timestep = 0.5
steps = 2
temperature_K = 300
spin_damping = 0.1
friction = 0.01

[output]
trajectory = "md.traj"
log = "md.log"
interval = 1
"""

#: What a value of CLI_SCENE is replaced with (TOML text)
CLI_VALUES = ["nan", "inf", "-1", "0", "1e300", "true", '"x"', "[]", "{}", "[1, 2]"]


def family_cli_inputs(quick=False):
    """``ase-spin run`` on CLI_SCENE with one value replaced (every value
    line, by each of :data:`CLI_VALUES`): it runs (exit 0) or refuses with
    exit 2 and one line on stderr, nothing written but the input file; no
    traceback, no exit 1 for an input error, no file left behind."""
    import contextlib
    import io
    import re

    from ase_spin.app.cli import main as cli_main

    lines = [k for k, line in enumerate(CLI_SCENE.splitlines())
             if re.match(r"^\w+ = ", line) and not line.startswith(("type", "build"))]
    values = CLI_VALUES[::3] if quick else CLI_VALUES
    cases = []
    for k in lines:
        key = CLI_SCENE.splitlines()[k].split(" = ")[0]
        for value in values:
            def act(atoms, k=k, value=value):
                text = CLI_SCENE.splitlines()
                text[k] = text[k].split(" = ")[0] + " = " + value
                folder = Path(tempfile.mkdtemp(prefix="fuzz-cli-"))
                (folder / "scene.toml").write_text("\n".join(text) + "\n")
                err = io.StringIO()
                with contextlib.redirect_stderr(err), \
                        contextlib.redirect_stdout(io.StringIO()):
                    code = cli_main(["run", str(folder / "scene.toml"), "--no-progress"])
                said = [s for s in err.getvalue().splitlines()
                        if not s.startswith("ase_spin: compiling") and "Warning" not in s
                        and not s.startswith("  ")]
                files = sorted(p.name for p in folder.iterdir())
                return {"code": code, "said": said, "files": files}

            def check(result, atoms):
                if result["code"] == 0:
                    return "md.traj" in result["files"]
                return (result["code"] == 2 and len(result["said"]) == 1
                        and result["said"][0].startswith("ase-spin: error:")
                        and result["files"] == ["scene.toml"])
            cases.append(Case("cli_inputs", f"{key} = {value}", act, expect="result",
                              check=check))
    return cases


def families(quick=False):
    """name -> list of cases (``quick``: the default test run's subset)."""
    return {
        "spins": family_spins(),
        "moments_dtype": family_moments_dtype(),
        "positions": family_positions(),
        "cell": family_cell(),
        "masses_momenta": family_masses_momenta(),
        "term_params": family_term_params(),
        "calculator_params": family_calculator_params(),
        "integrator_params": family_integrator_params(),
        "mutations": family_mutations(orders=(2,) if quick else (2, 4)),
        "interrupts": family_interrupts(stride=23 if quick else 1,
                                        combos=[(CollectivePRK, 2, False),
                                                (SuzukiTrotter, 2, True)] if quick else None),
        "files": family_files(stride=97 if quick else 1),
        "langevin": family_langevin(stride=61 if quick else 1),
        "systems": family_systems(),
        "security": family_security(),
        "cli_inputs": family_cli_inputs(quick),
        "symmetry": family_symmetry(quick),
        "eam_files": family_eam_files(quick),
        "lammps_files": family_lammps_files(quick),
        "tb2j": family_tb2j(quick),
        "ase_calculators": family_ase_calculators(quick),
    }


# -- isolation: child processes, restarted after a death ----------------------

def _plan(names, quick):
    """(family, index in the family) of every case of the families ``names``, in order."""
    built = families(quick)
    return built, [(family, index) for family in names for index in range(len(built[family]))]


def _child(names, start, quick):
    built, plan = _plan(names, quick)
    for position in range(start, len(plan)):
        family, index = plan[position]
        case = built[family][index]
        print(json.dumps({"start": position}), flush=True)
        verdict, detail = run_case(case)
        print(json.dumps({"position": position, "name": case.name, "verdict": verdict,
                          "detail": detail}), flush=True)


def run_isolated_all(names, quick=False, timeout=1800):
    """Run the cases of the families ``names``, one family after another, in
    child processes: one Python start for them all while none dies (a start
    and the kernels' first loads cost about as much as a quick family's
    cases). A case during which the child dies is a ``crash`` and the next
    child starts after it. Returns {family: [(name, verdict, detail), ...]}."""
    names = list(names)
    built, plan = _plan(names, quick)
    results = {}
    start = 0
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(HERE), PACKAGE_PATH, os.environ.get("PYTHONPATH", "")]))
    while start < len(plan):
        code = (f"import sys; sys.path.insert(0, {str(HERE)!r}); import fuzz; "
                f"fuzz._child({names!r}, {start}, {quick!r})")
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              timeout=timeout, env=env, cwd=tempfile.gettempdir())
        last_started = None
        for line in proc.stdout.splitlines():
            try:
                msg = json.loads(line)
            except ValueError:
                continue
            if "start" in msg:
                last_started = msg["start"]
            else:
                results[msg["position"]] = (msg["name"], msg["verdict"], msg["detail"])
        if proc.returncode == 0:
            break
        crashed = last_started if last_started is not None else start
        if crashed not in results:
            family, index = plan[crashed]
            results[crashed] = (built[family][index].name, "crash",
                                f"exit {proc.returncode}: {proc.stderr.strip()[-200:]}")
        start = crashed + 1
    outcome = {family: [] for family in names}
    for position, (family, index) in enumerate(plan):
        outcome[family].append(results.get(position, (built[family][index].name, "crash",
                                                      "never ran")))
    return outcome


def run_isolated(family, quick=False, timeout=1800):
    """:func:`run_isolated_all` of one family: its list of (name, verdict, detail)."""
    return run_isolated_all([family], quick, timeout)[family]


def campaign(quick=False, only=None, isolated=True):
    table = defaultdict(Counter)
    findings = []
    reports = []  # what the interrupt cases covered
    for family, cases in families(quick).items():
        if only and family not in only:
            continue
        if isolated:
            outcome = run_isolated(family, quick)
        else:
            outcome = [(c.name, *run_case(c)) for c in cases]
        for name, verdict, detail in outcome:
            table[family][verdict] += 1
            if verdict not in ("ok-error", "ok-result"):
                findings.append((family, name, verdict, detail))
            elif detail.startswith("{"):
                reports.append((family, name, verdict, detail))
    return table, findings, reports


def main(argv=None):
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the default test run's subset")
    parser.add_argument("--family", nargs="*", help="only these families")
    args = parser.parse_args(argv)
    table, findings, reports = campaign(args.quick, args.family)
    width = max(len(f) for f in table) if table else 6
    print(f"{'family':<{width}} " + " ".join(f"{v:>13}" for v in VERDICTS) + "   total")
    totals = Counter()
    for family, counts in table.items():
        totals.update(counts)
        print(f"{family:<{width}} " + " ".join(f"{counts[v]:>13}" for v in VERDICTS)
              + f"   {sum(counts.values()):>5}")
    print(f"{'all':<{width}} " + " ".join(f"{totals[v]:>13}" for v in VERDICTS)
          + f"   {sum(totals.values()):>5}")
    for family, name, verdict, detail in findings:
        print(f"[{verdict}] {family}: {name}: {detail}")
    for family, name, verdict, detail in reports:
        print(f"{family}: {name}: {detail}")
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())


# -- property-based (hypothesis) checks ------------------------------------------------

def hypothesis_cells(max_examples=60):
    """Random cells, periodicity and positions (edges included), in this
    process: each must give finite results or a ValueError naming the cell or
    pbc, with the Atoms unchanged. Run it in a child process (it is the family
    that used to kill the interpreter); returns the number of examples tried."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    edge = st.sampled_from([0.0, 5e-324, 1e-300, 1e-8, 1e8, 1e300, -3.0, math.nan, math.inf])
    entry = st.one_of(st.floats(-12.0, 12.0), edge)
    tried = [0]

    @settings(max_examples=max_examples, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(cell=st.lists(entry, min_size=9, max_size=9),
           pbc=st.lists(st.booleans(), min_size=3, max_size=3),
           shift=st.sampled_from([0.0, 3.0, -1e3, 1e6, 1e12]))
    def check(cell, pbc, shift):
        tried[0] += 1
        a = scene()
        a.cell.array[:] = np.reshape(cell, (3, 3))
        a.pbc = pbc
        a.positions[0] += shift
        before = fingerprint(a)
        try:
            out = _properties(a)
        except ValueError as err:
            assert any(k in str(err).lower() for k in ("cell", "pbc", "position", "closest")), err
            assert fingerprint(a) == before
            return
        assert all_finite(out), out

    check()
    return tried[0]


def hypothesis_spins(max_examples=200):
    """Random directions and magnitudes from all of float64: finite non-zero
    directions normalise to |s| = 1 within 4e-16; anything else is refused
    with the Atoms unchanged."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    tried = [0]

    @settings(max_examples=max_examples, deadline=None, database=None)
    @given(d=st.lists(st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True),
                      min_size=3, max_size=3),
           mu=st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True)))
    def check(d, mu):
        tried[0] += 1
        a = scene()
        before = fingerprint(a)
        d = np.array(d)
        try:
            ase_spin.set_spins(a, d, mu)
        except ValueError:
            assert fingerprint(a) == before
            ok_mu = mu is None or (math.isfinite(mu) and (mu == 0 or 1e-100 <= mu <= 1e100))
            assert not (np.isfinite(d).all() and d.any() and ok_mu)
            return
        s = ase_spin.get_spins(a)
        if not d.any() or mu == 0:
            assert not s.any()
            return
        assert np.abs(np.linalg.norm(s, axis=1) - 1.0).max() <= 4e-16
        scaled = d / np.abs(d).max()
        assert np.abs(s[0] - scaled / np.linalg.norm(scaled)).max() <= 2.3e-16

    check()
    return tried[0]
