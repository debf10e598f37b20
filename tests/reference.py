"""Plain numpy versions of the formulas, for checking the compiled kernels.

Independent of ase_spin's neighbour lists: pairs come from ASE's own
``ase.neighborlist.neighbor_list``.
"""

import numpy as np
from ase.neighborlist import neighbor_list


def lj_pair(r, eps, sigma, rc, mode, r_on=None):
    """u(r) and du/dr for one species pair (array r < rc)."""
    sr6 = (sigma / r) ** 6
    u = 4 * eps * (sr6**2 - sr6)
    du = 4 * eps * (-12 * sr6**2 + 6 * sr6) / r
    if mode == "shift":
        src6 = (sigma / rc) ** 6
        u = u - 4 * eps * (src6**2 - src6)
    elif mode == "smooth":
        ro = 0.66 * rc if r_on is None else r_on
        x, xc, xo = r**2, rc**2, ro**2
        S = np.where(x < xo, 1.0, (xc - x) ** 2 * (xc + 2 * x - 3 * xo) / (xc - xo) ** 3)
        dS = np.where(x < xo, 0.0, 6 * (xc - x) * (xo - x) / (xc - xo) ** 3 * 2 * r)
        du = du * S + u * dS
        u = u * S
    return u, du


def reference(atoms, lj=None, exchange=None, spins=None):
    """Energy, forces, magnetic forces and virial (3x3) of one-species LJ
    (eps, sigma, rc, mode) plus exchange (coupling J(r) callable returning
    (J, dJ), rc, offset) by brute force over ASE's full neighbour list."""
    n = len(atoms)
    E = 0.0
    F = np.zeros((n, 3))
    B = np.zeros((n, 3))
    W = np.zeros((3, 3))
    if n == 0:
        return E, F, B, W
    if lj is not None:
        eps, sigma, rc, mode = lj
        i, j, D = neighbor_list("ijD", atoms, rc)
        r = np.linalg.norm(D, axis=1)
        keep = r < rc
        i, j, D, r = i[keep], j[keep], D[keep], r[keep]
        u, du = lj_pair(r, eps, sigma, rc, mode)
        E += 0.5 * u.sum()
        np.add.at(F, i, (du / r)[:, None] * D)
        W += 0.5 * np.einsum("k,ka,kb->ab", du / r, D, D)
    if exchange is not None:
        values, rc, offset = exchange
        i, j, D = neighbor_list("ijD", atoms, rc)
        r = np.linalg.norm(D, axis=1)
        keep = r <= rc
        i, j, D, r = i[keep], j[keep], D[keep], r[keep]
        J, dJ = values(r)
        c = np.einsum("ka,ka->k", spins[i], spins[j]) - (1.0 if offset else 0.0)
        E += -0.5 * (J * c).sum()
        np.add.at(F, i, (-c * dJ / r)[:, None] * D)
        np.add.at(B, i, J[:, None] * spins[j])
        W += -0.5 * np.einsum("k,ka,kb->ab", c * dJ / r, D, D)
    return E, F, B, W
