"""The spherical midpoint update of one spin, compiled: the compensated sums,
the reflection s̃ = 2(s·W)W − s through the midpoint W, the locally exact
(Cayley) midpoint of a spin in the field of the others, and the sweeps in
colour order that the solvers build on."""

from __future__ import annotations

import numba as nb
import numpy as np

# Exit status of :func:`midpoint_solve`.
CONVERGED, ROUNDOFF, NOT_CONVERGED = 0, 1, 2


#: Earlier midpoint differences the default solver's Anderson acceleration keeps
#: (0: none, the plain fixed-point iteration); a longer memory saved no sweeps
#: (``git show 80c7697:docs/benchmarks.md``, "Tried and not kept").
MEMORY = 3
#: Steps with c_i|B̄_i| above this (rad, for a unit spin) are refused by the locally
#: exact update: its Cayley rotation angle 2 atan(c|B̄|/|v|) saturates at π, so such a step
#: is no longer a step of the dynamics (fcc Co: c|B̄| ≈ 4.4 at 8 fs).
MAX_TURN = 8.0
#: Atoms per block of the Anderson inner products: a partition fixed whatever
#: the thread count, its partial sums added in block order, so that every bit of
#: the result is the same for any number of threads.
BLOCK = 256


@nb.njit(cache=True, inline="always")
def _add_compensated(i, sx, sy, sz, ax, ay, az, stilde, carry_out):
    """stilde_i = s_i + a (a: the increment with the carried rounding error
    added), its rounding error into ``carry_out`` (Kahan)."""
    tx = sx + ax
    ty = sy + ay
    tz = sz + az
    carry_out[i, 0] = ax - (tx - sx)
    carry_out[i, 1] = ay - (ty - sy)
    carry_out[i, 2] = az - (tz - sz)
    stilde[i, 0] = tx
    stilde[i, 1] = ty
    stilde[i, 2] = tz


@nb.njit(cache=True, inline="always")
def _reflect(i, s, wx, wy, wz, bx, by, bz, scale, stilde, carry, carry_out):
    """End point of spin i (into ``stilde``, its rounding error into
    ``carry_out``) for midpoint direction W_i = (wx, wy, wz) and midpoint field
    B̄_i = (bx, by, bz), as the reflection of s_i about v = 2 s_i + c_i W_i × B̄_i
    (see :func:`update_row`). Returns (v, |v|²)."""
    sx = s[i, 0]
    sy = s[i, 1]
    sz = s[i, 2]
    cx = carry[i, 0]
    cy = carry[i, 1]
    cz = carry[i, 2]
    c = scale[i]
    dx = c * (wy * bz - wz * by)
    dy = c * (wz * bx - wx * bz)
    dz = c * (wx * by - wy * bx)
    vx = 2.0 * (sx + cx) + dx
    vy = 2.0 * (sy + cy) + dy
    vz = 2.0 * (sz + cz) + dz
    vv = vx * vx + vy * vy + vz * vz
    # the spin is s + carry (the carried rounding error): keep its length
    kappa = (2.0 * ((sx * dx + sy * dy + sz * dz) + (cx * dx + cy * dy + cz * dz))
             + (dx * dx + dy * dy + dz * dz)) / vv
    _add_compensated(i, sx, sy, sz, cx + (dx - kappa * vx), cy + (dy - kappa * vy),
                     cz + (dz - kappa * vz), stilde, carry_out)
    return vx, vy, vz, vv


@nb.njit(cache=True, inline="always")
def pinned_row(i, s, cur, nxt, stilde, carry, carry_out):
    """A spin of precession rate 0 (c_i = 0: pinned, ase_spin.FixSpins): its
    midpoint and its end point are the spin itself, copied (the arithmetic of
    a zero step would leave round-off in W_i, a −0.0 turned into 0.0 in s̃_i);
    its carried rounding error stays as it was. Returns max |ΔW_i|."""
    sx = s[i, 0]
    sy = s[i, 1]
    sz = s[i, 2]
    stilde[i, 0] = sx
    stilde[i, 1] = sy
    stilde[i, 2] = sz
    carry_out[i, 0] = carry[i, 0]
    carry_out[i, 1] = carry[i, 1]
    carry_out[i, 2] = carry[i, 2]
    nxt[i, 0] = sx
    nxt[i, 1] = sy
    nxt[i, 2] = sz
    return max(abs(sx - cur[i, 0]), abs(sy - cur[i, 1]), abs(sz - cur[i, 2]))


@nb.njit(cache=True, inline="always")
def update_row(i, s, cur, nxt, bx, by, bz, scale, stilde, carry, carry_out):
    """One spin's Jacobi update given its midpoint field B̄_i = (bx, by, bz).

    With d = c_i W_i × B̄_i (c_i = ``scale[i]``, hσ/ħ times the spin's
    precession rate factor) and v = 2 s_i + d (= s_i + s̃_i), the next iterate is
    W_i = v/|v| and the end point is

        s̃_i = s_i + d − κ v,   κ = (2 s_i·d + |d|²)/|v|²,

    the reflection of s_i about v: equal to s_i + d at the solution (κ = 0),
    and |s̃_i| = |s_i| to round-off whatever residual the iteration stops with
    (κ, the length error a residual would cause, is computed from the increment
    d, without cancellation). s_i is the stored spin plus the rounding error
    carried from the last step, and the sum is compensated (Kahan). A pinned
    spin (c_i = 0) is copied (:func:`pinned_row`).
    Returns max |ΔW_i| over components.
    """
    if scale[i] == 0.0:
        return pinned_row(i, s, cur, nxt, stilde, carry, carry_out)
    wx = cur[i, 0]
    wy = cur[i, 1]
    wz = cur[i, 2]
    vx, vy, vz, vv = _reflect(i, s, wx, wy, wz, bx, by, bz, scale, stilde, carry, carry_out)
    inv = 1.0 / np.sqrt(vv)
    vx *= inv
    vy *= inv
    vz *= inv
    nxt[i, 0] = vx
    nxt[i, 1] = vy
    nxt[i, 2] = vz
    return max(abs(vx - wx), abs(vy - wy), abs(vz - wz))


@nb.njit(cache=True, inline="always")
def local_midpoint(px, py, pz, bx, by, bz, c):
    r"""The midpoint direction of one spin p in a fixed field b: the unit W with

    .. math:: \mathbf W = \frac{\mathbf v}{|\mathbf v|}, \qquad
              \mathbf v = 2\mathbf p + c\, \mathbf W \times \mathbf b

    (the spherical midpoint step of ṗ ∝ p × b: a Cayley rotation about b).
    With λ = |v| and a = c/λ the equation is linear in v, v − a v × b = 2p, so

    .. math:: \mathbf v \propto \mathbf p + a\, \mathbf p \times \mathbf b
              + a^2 (\mathbf p\cdot\mathbf b)\, \mathbf b, \qquad
              |\mathbf v|^2 = 4\frac{|p|^2 + a^2 (p\cdot b)^2}{1 + a^2 |b|^2},

    and y = λ² is the positive root of y² − (4|p|² − c²|b|²) y − 4c²(p·b)² = 0
    (taken in the form without cancellation). Returns (Wx, Wy, Wz, found):
    no root when p ⊥ b and |c b| ≥ 2|p| (a half-turn or more per step)."""
    wx, wy, wz, _, _, _, found = local_midpoint_split(px, py, pz, bx, by, bz, c)
    return wx, wy, wz, found


@nb.njit(cache=True, inline="always")
def local_midpoint_split(px, py, pz, bx, by, bz, c):
    r""":func:`local_midpoint`'s W and its part beyond the spin,
    E = W − g p = g (a p × b + a²(p·b) b): small for a small step and computed
    without cancellation, so that p × W = p × E is known to round-off in E, not
    to round-off in W (which, once W is rounded to a unit vector, is ε absolute:
    an end point made from the rounded W alone moves the spin by ~2ε a step,
    whatever the step). Returns (Wx, Wy, Wz, Ex, Ey, Ez, found)."""
    pp = px * px + py * py + pz * pz
    pb = px * bx + py * by + pz * bz
    cc = c * c
    cb = cc * (bx * bx + by * by + bz * bz)
    q = 4.0 * pp - cb
    r = 4.0 * cc * pb * pb
    root = np.sqrt(q * q + 4.0 * r)
    if q >= 0.0:
        y = 0.5 * (q + root)
    else:
        y = 2.0 * r / (root - q)
    if not y > 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    sy = np.sqrt(y)
    a = c / sy
    f = a * a * pb
    # W = v/λ = 2 sqrt(y) v'/(y + c²|b|²) with v' = p + a p × b + a²(p·b) b: unit,
    # as y(y + c²|b|²) = 4(|p|² y + c²(p·b)²) is the equation of y
    g = 2.0 * sy / (y + cb)
    tx = a * (py * bz - pz * by)
    ty = a * (pz * bx - px * bz)
    tz = a * (px * by - py * bx)
    ux = f * bx
    uy = f * by
    uz = f * bz
    return (g * (px + tx + ux), g * (py + ty + uy), g * (pz + tz + uz),
            g * (tx + ux), g * (ty + uy), g * (tz + uz), True)




@nb.njit(cache=True, inline="always")
def local_midpoint_direction(i, s, cur, nxt, bx, by, bz, scale, stilde, carry, carry_out,
                              jacobi_rows):
    """One spin's locally exact update: W_i solved exactly for the field B̄_i =
    (bx, by, bz) of the current iterate (:func:`local_midpoint`, for the spin
    p = s_i + carry), the next iterate. Its end point is left to
    :func:`end_points_of_rows` after the last sweep: it depends on that sweep's W_i
    and E_i = W_i − g p only (:func:`local_midpoint_split`; E_i is left in
    ``stilde``), so it is made once a solve, not once a sweep. Where the local equation has no root, the Jacobi update
    of :func:`update_row`, end point included, the row marked in
    ``jacobi_rows``. A pinned spin (c_i = 0) is copied, end point included
    (:func:`pinned_row`), and marked there too. Returns max |ΔW_i| over
    components, or 4 (more than any change of unit vectors: "not converged")
    where c_i|B̄_i| > :data:`MAX_TURN` |s_i|."""
    c = scale[i]
    if c == 0.0:
        jacobi_rows[i] = True  # (its end point is written)
        return pinned_row(i, s, cur, nxt, stilde, carry, carry_out)
    px = s[i, 0] + carry[i, 0]
    py = s[i, 1] + carry[i, 1]
    pz = s[i, 2] + carry[i, 2]
    jacobi_rows[i] = False
    if c * c * (bx * bx + by * by + bz * bz) > MAX_TURN * MAX_TURN * (px * px + py * py
                                                                      + pz * pz):
        return 4.0  # refused: reported as not converged (see MAX_TURN)
    wx, wy, wz, ex, ey, ez, found = local_midpoint_split(px, py, pz, bx, by, bz, c)
    if not found:
        jacobi_rows[i] = True
        return update_row(i, s, cur, nxt, bx, by, bz, scale, stilde, carry, carry_out)
    # W's part beyond the spin, for the end point (end_points_of_rows reads it
    # there and writes the end point over it)
    stilde[i, 0] = ex
    stilde[i, 1] = ey
    stilde[i, 2] = ez
    ox = cur[i, 0]
    oy = cur[i, 1]
    oz = cur[i, 2]
    nxt[i, 0] = wx
    nxt[i, 1] = wy
    nxt[i, 2] = wz
    return max(abs(wx - ox), abs(wy - oy), abs(wz - oz))


@nb.njit(cache=True, inline="always")
def end_points_of_rows(lo, hi, s, W, stilde, carry, carry_out, jacobi_rows):
    r"""End points of rows lo … hi − 1 after locally exact sweeps
    (:func:`local_midpoint_direction`): s̃_i the reflection of the spin
    p = s_i + carry_i about the last sweep's result W_i (which is v/|v| for
    v = 2p + c_i W_i × B̄_i: the reflection :func:`_reflect` makes), written as
    the increment

    .. math:: \tilde{\mathbf s}_i - \mathbf p = 2 (\mathbf p \times \mathbf W_i)
              \times \mathbf W_i, \qquad \mathbf p \times \mathbf W_i
              = \mathbf p \times \mathbf E_i,

    E_i = W_i − g_i p the last sweep's part of W_i beyond the spin, which
    :func:`local_midpoint_direction` left in ``stilde`` (read here, then
    overwritten by the end point). p × W_i from the rounded unit W_i would
    cancel: its error, ε absolute rather than ε|p × W_i|, would move every
    spin by ~2ε a step whatever the step, and over 2^17–2^20 steps of the
    paper chain that outgrew the h² error (docs/paper.md, Figure 2). E_i is
    small for a small step and known to its own round-off. The sum is
    compensated as in :func:`_reflect`. |s̃_i|² = |p|² to round-off in the
    increment. No field, no division. Rows without spin, and those the Jacobi
    update or :func:`pinned_row` took (``jacobi_rows``: they wrote their end
    points), are skipped."""
    for i in range(lo, hi):
        sx = s[i, 0]
        sy = s[i, 1]
        sz = s[i, 2]
        if jacobi_rows[i] or (sx == 0.0 and sy == 0.0 and sz == 0.0):
            continue
        cx = carry[i, 0]
        cy = carry[i, 1]
        cz = carry[i, 2]
        wx = W[i, 0]
        wy = W[i, 1]
        wz = W[i, 2]
        # u = p × W = p × E, E = W − g p the last sweep's part of W beyond the
        # spin (local_midpoint_direction left it in stilde): p × W from the
        # rounded W would carry W's rounding (ε, not ε|p × W|) into the end
        # point every step; the carry's part kept apart from the spin's
        ex = stilde[i, 0]
        ey = stilde[i, 1]
        ez = stilde[i, 2]
        ux = (sy * ez - sz * ey) + (cy * ez - cz * ey)
        uy = (sz * ex - sx * ez) + (cz * ex - cx * ez)
        uz = (sx * ey - sy * ex) + (cx * ey - cy * ex)
        _add_compensated(i, sx, sy, sz, cx + 2.0 * (uy * wz - uz * wy),
                         cy + 2.0 * (uz * wx - ux * wz), cz + 2.0 * (ux * wy - uy * wx),
                         stilde, carry_out)


@nb.njit(cache=True, inline="always")
def pair_field_row(i, row, nbr, Jbar, source):
    """B̄_i = Σ_k J̄_k source_j over row i's pairs k = (i → j) of a full list."""
    bx = 0.0
    by = 0.0
    bz = 0.0
    for k in range(row[i], row[i + 1]):
        j = nbr[k]
        Jk = Jbar[k]
        bx += Jk * source[j, 0]
        by += Jk * source[j, 1]
        bz += Jk * source[j, 2]
    return bx, by, bz


@nb.njit(cache=True)
def coloured_spins(lo, hi, row, nbr, Jbar, s, cur, nxt, scale, stilde, carry, carry_out,
                    jacobi_rows, field, order):
    """The locally exact updates of the spins ``order[lo:hi]`` in turn, in
    place in ``nxt`` (:func:`midpoint_solve`): each in its field there, where
    the spins updated before it are already new and the rest still the
    iterate's. The rows are in ``order`` (row a is spin ``order[a]``'s:
    neighbors.rows_in_order). Returns max |ΔW| over their components."""
    m = 0.0
    for a in range(lo, hi):
        i = order[a]
        if s[i, 0] == 0.0 and s[i, 1] == 0.0 and s[i, 2] == 0.0:
            continue
        bx, by, bz = pair_field_row(a, row, nbr, Jbar, nxt)
        if field is not None and field.shape[0] > 0:
            field[i, 0] = bx
            field[i, 1] = by
            field[i, 2] = bz
        d = local_midpoint_direction(i, s, cur, nxt, bx, by, bz, scale, stilde, carry,
                                      carry_out, jacobi_rows)
        if not d <= m and m == m:  # a NaN stays (max(m, d) drops it)
            m = d
    return m


@nb.njit(cache=True)
def coloured_sweep(row, nbr, Jbar, s, cur, nxt, scale, stilde, carry, carry_out, jacobi_rows,
                    field, order):
    """A locally exact sweep in colour order (:func:`midpoint_solve`), serial:
    g(W) made in place in ``nxt`` (W copied in first), each spin in ``order``
    (the atoms colour by colour) in its field there, where the colours before
    its own are already new and the rest still W's (:func:`coloured_spins`).
    One colour's spins are not paired, so their order does not matter.
    Returns max |ΔW| over all components."""
    for i in range(s.shape[0]):
        nxt[i, 0] = cur[i, 0]
        nxt[i, 1] = cur[i, 1]
        nxt[i, 2] = cur[i, 2]
    # np.int64(0), not 0: a literal would compile coloured_spins a second time
    return coloured_spins(np.int64(0), len(order), row, nbr, Jbar, s, cur, nxt, scale, stilde,
                          carry, carry_out, jacobi_rows, field, order)
