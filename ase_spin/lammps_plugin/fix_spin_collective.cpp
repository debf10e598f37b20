/* fix spin/collective: the collective symplectic PRK step of ase_spin as a
   LAMMPS fix (see fix_spin_collective.h and README.md in this folder).

   Part of the ase_spin LAMMPS plugin. Copyright (C) 2025 the ase_spin authors.

   This program is free software; you can redistribute it and/or modify it
   under the terms of the GNU General Public License as published by the Free
   Software Foundation; either version 2 of the License, or (at your option)
   any later version. It links against LAMMPS (GPL-2) and is a derivative work
   of it; see LICENSE in this folder.

   One step of size h (ase_spin.md.collective.CollectivePRK; metal units, so
   the field is LAMMPS's fm = B/hbar in rad/ps and ds/dt = fm x s):

     P  = v + (h/2) F(q, W)/m,          q~ = q + h P,
     s~ = s + h (Bbar x W),             Bbar = [fm(q, W) + fm(q~, W)]/2,
     W  = (s + s~)/|s + s~|,            v~ = P + (h/2) F(q~, W)/m.

   The implicit equations are solved to round-off: outer rounds (forces at
   (q, W), kick and drift) around midpoint solves; each solve sweeps all spins
   at once, every spin's midpoint solved exactly in the field of the others'
   current iterate (a Cayley rotation about Bbar_i), with the ghost spins
   exchanged before every field evaluation and the largest change taken over
   all ranks, so that every rank sweeps the same number of times and no
   result depends on the domain decomposition (up to the order of the
   floating-point sums inside the pair styles). Each solve starts from a
   guess extrapolated from the atom's own increments W - s of the last steps
   (predict()), which the atom carries between ranks. Orders 4 and 6: Suzuki's
   five-stage and Kahan–Li's nine-stage compositions of this step. */

#include "fix_spin_collective.h"

#include "atom.h"
#include "comm.h"
#include "error.h"
#include "force.h"
#include "memory.h"
#include "modify.h"
#include "pair.h"
#include "update.h"
#include "utils.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstring>

using namespace LAMMPS_NS;
using namespace FixConst;

namespace {

// Outer rounds (q~ and W settling together) a step may take: as ase_spin.md.policy.MAX_ROUNDS.
constexpr int MAX_ROUNDS = 12;
// ase_spin.md.policy: the solvers' round-off floor (FLOOR_FACTOR tol) and how far W may
// move in an outer round for the kick and drift made from the W before it to stand.
constexpr double FLOOR_FACTOR = 64.0;
constexpr double SETTLED_FACTOR = 8.0;
// Increments W - s kept per atom and stage for the first guess of the midpoint
// spins (a polynomial through them, one step ahead): the one-stage step, the
// compositions (memory: 3 doubles per increment, stage and atom).
constexpr int PREDICTOR_DEPTH = 6;
constexpr int PREDICTOR_DEPTH_STAGES = 4;

// ase_spin.md.compositions: Suzuki's five-stage order 4, Kahan & Li's nine-stage order 6.
std::vector<double> composition(int order)
{
  if (order == 4) {
    const double c = std::cbrt(4.0), g = 1.0 / (4.0 - c);
    return {g, g, -c * g, g, g};
  }
  if (order == 6) {
    const double a[4] = {0.39216144400731413928, 0.33259913678935943860,
                         -0.70624617255763935981, 0.08221359629355080023};
    const double mid = 0.79854399093482996340;
    return {a[0], a[1], a[2], a[3], mid, a[3], a[2], a[1], a[0]};
  }
  return {1.0};
}

/* The midpoint W of a spin p in a fixed field b for the step v = 2p + c W x b
   (W = v/|v|): with y = |v|^2 the positive root of
   y^2 - (4|p|^2 - c^2|b|^2) y - 4 c^2 (p.b)^2 = 0 (taken without cancellation),
   a = c/sqrt(y), W = g (p + a p x b + a^2 (p.b) b), g = 2 sqrt(y)/(y + c^2|b|^2).
   ase_spin.md.kernels.midpoint.local_midpoint_split. Returns false where no root
   exists (p perpendicular to b and a half turn or more per step). */
bool local_midpoint(const double *p, const double *b, double c, double *w)
{
  const double pp = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
  const double pb = p[0] * b[0] + p[1] * b[1] + p[2] * b[2];
  const double cc = c * c;
  const double cb = cc * (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
  const double q = 4.0 * pp - cb;
  const double r = 4.0 * cc * pb * pb;
  const double root = std::sqrt(q * q + 4.0 * r);
  const double y = (q >= 0.0) ? 0.5 * (q + root) : 2.0 * r / (root - q);
  if (!(y > 0.0)) return false;
  const double sy = std::sqrt(y);
  const double a = c / sy;
  const double f = a * a * pb;
  const double g = 2.0 * sy / (y + cb);
  w[0] = g * (p[0] + a * (p[1] * b[2] - p[2] * b[1]) + f * b[0]);
  w[1] = g * (p[1] + a * (p[2] * b[0] - p[0] * b[2]) + f * b[1]);
  w[2] = g * (p[2] + a * (p[0] * b[1] - p[1] * b[0]) + f * b[2]);
  return true;
}

}    // namespace

/* ---------------------------------------------------------------------- */

FixSpinCollective::FixSpinCollective(LAMMPS *lmp, int narg, char **arg) :
    Fix(lmp, narg, arg), moving(1), tol(1e-15), max_iter(100), initialised(false),
    history(nullptr), depth(0), history_width(0), stage(0),
    sweeps_step(0.0), rounds_step(0.0), sweeps_total(0.0), forward_step(0.0),
    reverse_step(0.0), reduce_step(0.0)
{
  if (!atom->sp_flag) error->all(FLERR, "Fix spin/collective requires atom_style spin");
  if (igroup != 0) error->all(FLERR, "Fix spin/collective must act on group all");
  time_integrate = 1;
  vector_flag = 1;
  size_vector = 7;
  global_freq = 1;
  extvector = 0;

  int order = 2;
  bool lattice_given = false;
  int iarg = 3;
  while (iarg < narg) {
    const std::string key = arg[iarg];
    if (iarg + 2 > narg) error->all(FLERR, "Fix spin/collective: keyword {} needs a value", key);
    const std::string value = arg[iarg + 1];
    if (key == "lattice") {
      if (value == "moving") moving = 1;
      else if (value == "frozen") moving = 0;
      else error->all(FLERR, "Fix spin/collective: lattice must be moving or frozen, got {}", value);
      lattice_given = true;
    } else if (key == "order") {
      order = utils::inumeric(FLERR, value, false, lmp);
      if (order != 2 && order != 4 && order != 6)
        error->all(FLERR, "Fix spin/collective: order must be 2, 4 or 6, got {}", value);
    } else if (key == "tol") {
      tol = utils::numeric(FLERR, value, false, lmp);
      if (!(tol >= 1e-16 && tol <= 1e-3))
        error->all(FLERR, "Fix spin/collective: tol must lie between 1e-16 and 1e-3, got {}",
                   value);
    } else if (key == "max_iter") {
      max_iter = utils::inumeric(FLERR, value, false, lmp);
      if (max_iter < 1) error->all(FLERR, "Fix spin/collective: max_iter must be >= 1");
    } else {
      error->all(FLERR, "Fix spin/collective: unknown keyword {} (lattice, order, tol, max_iter)",
                 key);
    }
    iarg += 2;
  }
  if (!lattice_given)
    error->all(FLERR, "Fix spin/collective: the keyword lattice (moving or frozen) is required");
  gammas = composition(order);
  depth = gammas.size() == 1 ? PREDICTOR_DEPTH : PREDICTOR_DEPTH_STAGES;
  history_width = 1 + 3 * depth * static_cast<int>(gammas.size());
  maxexchange = history_width;
  create_attribute = 1;    // atoms created later start without history (set_arrays)
  grow_arrays(atom->nmax);
  atom->add_callback(Atom::GROW);
  for (int i = 0; i < atom->nlocal; i++) history[i][0] = 0.0;
  floor_tol = FLOOR_FACTOR * tol;
  settled_tol = SETTLED_FACTOR * tol;
  if (moving && atom->map_style == Atom::MAP_NONE)
    error->all(FLERR, "Fix spin/collective with lattice moving needs an atom map "
                      "(atom_modify map array)");
}

/* ---------------------------------------------------------------------- */

FixSpinCollective::~FixSpinCollective()
{
  atom->delete_callback(id, Atom::GROW);
  memory->destroy(history);
  // a carrier never used by an init (the fix removed before any run)
  if (!initialised && !carrier_id.empty() && modify && modify->get_fix_by_id(carrier_id))
    modify->delete_fix(carrier_id);
}

int FixSpinCollective::setmask()
{
  return INITIAL_INTEGRATE;
}

/* The spin pair styles compute their lattice (mechanical) forces only when,
   at their init, exactly one fix of a style beginning with nve/spin says
   "lattice moving" (PairSpin::init_style reads its lattice_flag). This fix
   therefore adds such a fix (the carrier) after itself; the pair styles read
   it at the next init, and this fix's init(), which runs after theirs and
   before the carrier's, deletes it again, so that it never integrates. The
   flag stays set in the pair styles for later runs (see init()). */
void FixSpinCollective::post_constructor()
{
  if (!moving) return;
  carrier_id = std::string(id) + "_lattice_forces";
  if (!modify->get_fix_by_id(carrier_id))
    modify->add_fix(carrier_id + " all nve/spin lattice moving");
}

/* ---------------------------------------------------------------------- */

void FixSpinCollective::init()
{
  if (force->kspace)
    error->all(FLERR, "Fix spin/collective does not support kspace styles (spin/long)");
  if (!force->pair) error->all(FLERR, "Fix spin/collective needs a pair style");
  if (!force->newton_pair) error->all(FLERR, "Fix spin/collective needs newton pair on");

  // the spin pair styles (pair_match returns the single match again for any
  // instance number: stop at a repeat)
  spin_pairs.clear();
  for (int k = 1; k < 64; k++) {
    Pair *p = force->pair_match("^spin", 0, k);
    if (!p) break;
    bool seen = false;
    for (auto q : spin_pairs) seen = seen || (q == p);
    if (seen) break;
    spin_pairs.push_back(p);
  }

  // the fixes that add to the spins' fields, in LAMMPS's order: precession, then setforce
  field_fixes.clear();
  for (auto f : modify->get_fix_by_style("^precession/spin")) field_fixes.push_back(f);
  for (auto f : modify->get_fix_by_style("^setforce/spin")) field_fixes.push_back(f);
  if (!modify->get_fix_by_style("^langevin/spin").empty())
    error->all(FLERR, "Fix spin/collective has no spin thermostat: fix langevin/spin acts only "
                      "inside fix nve/spin's sequential update (equilibrate with fix nve/spin "
                      "and fix langevin/spin, then unfix them and define fix spin/collective)");
  for (auto f : modify->get_fix_by_style("^nve/spin"))
    if (carrier_id.empty() || carrier_id != f->id)
      error->all(FLERR, "Fix spin/collective and fix {} ({}) both integrate the spins", f->id,
                 f->style);
  /* The step computes its forces and fields itself, inside initial_integrate:
     a fix that adds forces after LAMMPS's force evaluation (post_force: fix
     langevin, addforce, setforce, efield, ...) would change only that end-of-
     step evaluation, which the next step does not read, so it would be
     silently without effect: refused. Fixes acting between steps on x or v
     (fix temp/csvr, temp/berendsen, momentum, ...) do act. */
  for (int k = 0; k < modify->nfix; k++) {
    Fix *f = modify->fix[k];
    if (f == this || (!carrier_id.empty() && carrier_id == f->id)) continue;
    if (utils::strmatch(f->style, "^precession/spin") || utils::strmatch(f->style, "^setforce/spin"))
      continue;    // in the fields the step evaluates
    if (f->time_integrate)
      error->all(FLERR, "Fix spin/collective and fix {} ({}) both integrate the atoms", f->id,
                 f->style);
    if (modify->fmask[k] & POST_FORCE)
      error->all(FLERR, "Fix spin/collective computes forces inside its step; fix {} ({}) adds "
                        "forces after them (post_force), which the step would not see: not "
                        "supported (a lattice thermostat acting between steps, fix temp/csvr "
                        "or temp/berendsen, works)", f->id, f->style);
  }

  if (moving) {
    if (!carrier_id.empty() && modify->get_fix_by_id(carrier_id)) {
      // the pair styles have read the carrier (force->init runs before modify->init):
      // delete it before its own init, so that it never runs
      modify->delete_fix(carrier_id);
      first_pairs = spin_pairs;
    } else if (spin_pairs != first_pairs) {
      error->all(FLERR, "Fix spin/collective: the spin pair styles were redefined after the "
                        "fix; define the fix again (unfix, fix) so that their lattice forces "
                        "are switched on");
    }
  }
  initialised = true;
}

/* ---------------------------------------------------------------------- */

double FixSpinCollective::global_max(double value)
{
  reduce_step += 1.0;
  double all;
  MPI_Allreduce(&value, &all, 1, MPI_DOUBLE, MPI_MAX, world);
  return all;
}

/* Forward (positions and spins to the ghosts) and reverse (ghost forces and
   fields to their owners) communication, counted. */
void FixSpinCollective::forward()
{
  forward_step += 1.0;
  comm->forward_comm();
}

void FixSpinCollective::reverse()
{
  reverse_step += 1.0;
  comm->reverse_comm();
}

/* Local positions and spin directions set to pos and spins (3 per local atom), then
   the ghosts brought up to date (forward communication: x and sp). */
void FixSpinCollective::put_state(const std::vector<double> &pos,
                                  const std::vector<double> &spins)
{
  double **x = atom->x;
  double **sp = atom->sp;
  const int n = atom->nlocal;
  for (int i = 0; i < n; i++)
    for (int d = 0; d < 3; d++) {
      x[i][d] = pos[3 * i + d];
      sp[i][d] = spins[3 * i + d];
    }
  forward();
}

/* fm (rad/ps) of the local atoms at the state put_state set: the spin pair styles,
   then the precession and setforce fixes. */
void FixSpinCollective::fields(std::vector<double> &out)
{
  const int nall = atom->nlocal + atom->nghost;
  double **fm = atom->fm;
  std::memset(&fm[0][0], 0, sizeof(double) * 3 * nall);
  if (atom->fm_long) std::memset(&atom->fm_long[0][0], 0, sizeof(double) * 3 * nall);
  for (auto p : spin_pairs) p->compute(0, 0);
  for (auto f : field_fixes) f->post_force(0);
  const int n = atom->nlocal;
  for (int i = 0; i < n; i++)
    for (int d = 0; d < 3; d++) out[3 * i + d] = fm[i][d];
}

/* Forces (eV/Å) on the local atoms at the state put_state set: every pair style. */
void FixSpinCollective::forces(std::vector<double> &out)
{
  const int nall = atom->nlocal + atom->nghost;
  std::memset(&atom->f[0][0], 0, sizeof(double) * 3 * nall);
  std::memset(&atom->fm[0][0], 0, sizeof(double) * 3 * nall);
  if (atom->fm_long) std::memset(&atom->fm_long[0][0], 0, sizeof(double) * 3 * nall);
  force->pair->compute(0, 0);
  if (force->newton_pair) reverse();
  double **f = atom->f;
  const int n = atom->nlocal;
  for (int i = 0; i < n; i++)
    for (int d = 0; d < 3; d++) out[3 * i + d] = f[i][d];
}

/* ---------------------------------------------------------------------- */

void FixSpinCollective::initial_integrate(int /*vflag*/)
{
  sweeps_step = rounds_step = forward_step = reverse_step = reduce_step = 0.0;
  for (stage = 0; stage < static_cast<int>(gammas.size()); stage++)
    substep(gammas[stage] * update->dt);
  for (int i = 0; i < atom->nlocal; i++)
    history[i][0] = std::min(history[i][0] + 1.0, static_cast<double>(depth));
  sweeps_total += sweeps_step;
}

/* The first guess of the midpoint spin of atom i at this stage: s plus the
   polynomial through the increments W - s of the same stage in its last m steps
   (m = those recorded, up to depth) taken one step ahead,
   sum_j (-1)^(j+1) C(m, j) d_j (d_1 the newest; m = 0: s itself). Only the
   number of sweeps depends on it (the solve runs to tol from any guess), and it
   depends only on the atom's own past, so the trajectory still does not depend
   on the ranks. */
void FixSpinCollective::predict(int i, const double *s, double *w) const
{
  const int m = static_cast<int>(history[i][0]);
  const double *d = &history[i][1 + 3 * depth * stage];
  double c = 1.0, sign = 1.0;
  for (int k = 0; k < 3; k++) w[k] = s[k];
  for (int j = 1; j <= m && j <= depth; j++) {
    c = c * (m - j + 1) / j;    // C(m, j)
    for (int k = 0; k < 3; k++) w[k] += sign * c * d[3 * (j - 1) + k];
    sign = -sign;
  }
  const double norm = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
  const bool usable = norm > 0.5 && norm < 2.0;    // (no history, or a broken one: s)
  for (int k = 0; k < 3; k++) w[k] = usable ? w[k] / norm : s[k];
}

/* This stage's increments W - s into the atoms' history (the older ones shifted). */
void FixSpinCollective::record()
{
  for (int i = 0; i < atom->nlocal; i++) {
    double *d = &history[i][1 + 3 * depth * stage];
    for (int k = 3 * depth - 1; k >= 3; k--) d[k] = d[k - 3];
    for (int k = 0; k < 3; k++) d[k] = W[3 * i + k] - s0[3 * i + k];
  }
}

/* ---------------------------------------------------------------------- */

void FixSpinCollective::grow_arrays(int nmax)
{
  memory->grow(history, nmax, history_width, "spin/collective:history");
}

void FixSpinCollective::set_arrays(int i)
{
  history[i][0] = 0.0;
}

void FixSpinCollective::copy_arrays(int i, int j, int /*delflag*/)
{
  for (int k = 0; k < history_width; k++) history[j][k] = history[i][k];
}

int FixSpinCollective::pack_exchange(int i, double *buf)
{
  for (int k = 0; k < history_width; k++) buf[k] = history[i][k];
  return history_width;
}

int FixSpinCollective::unpack_exchange(int nlocal, double *buf)
{
  for (int k = 0; k < history_width; k++) history[nlocal][k] = buf[k];
  return history_width;
}

double FixSpinCollective::memory_usage()
{
  return static_cast<double>(atom->nmax) * history_width * sizeof(double);
}

/* The midpoint spins W for the fields at q (and q~: mean), from the current W, to
   tol: locally exact sweeps over all spins at once (Jacobi order: each spin
   in the field of the others' last iterate, so the result does not depend on
   the order of the atoms or their ranks). moved: how far W went (max over
   components and ranks). The stopping rule is ase_spin's
   (ase_spin.md.kernels.anderson.after_sweep). */
void FixSpinCollective::solve(double h, bool mean, double &moved)
{
  const int n = atom->nlocal;
  const double c = -h;    // s~ - s = c W x Bbar with LAMMPS's fm: ds/dt = fm x s
  double **sp = atom->sp;
  std::vector<double> W_start(W);
  double previous = 0.0, theta = 1.0;
  for (int it = 1; it <= max_iter; it++) {
    put_state(q0, W);
    fields(Ba);
    if (mean) {
      put_state(qt, W);
      fields(Bb);
    }
    double local = 0.0;
    for (int i = 0; i < n; i++) {
      double *w = &Wn[3 * i];
      const double *p = &s0[3 * i];
      if (sp[i][3] == 0.0) {    // no moment: the spin stays
        w[0] = p[0], w[1] = p[1], w[2] = p[2];
        continue;
      }
      double b[3];
      for (int d = 0; d < 3; d++)
        b[d] = mean ? 0.5 * (Ba[3 * i + d] + Bb[3 * i + d]) : Ba[3 * i + d];
      if (!local_midpoint(p, b, c, w)) {
        // a half turn or more per step: the plain fixed-point update v = 2p + c W x b
        const double *u = &W[3 * i];
        double v[3] = {2.0 * p[0] + c * (u[1] * b[2] - u[2] * b[1]),
                       2.0 * p[1] + c * (u[2] * b[0] - u[0] * b[2]),
                       2.0 * p[2] + c * (u[0] * b[1] - u[1] * b[0])};
        const double inv = 1.0 / std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        for (int d = 0; d < 3; d++) w[d] = v[d] * inv;
      }
      for (int d = 0; d < 3; d++) {
        const double change = std::fabs(w[d] - W[3 * i + d]);
        if (!(change <= local)) local = change;    // (a NaN stays)
      }
    }
    const double delta = global_max(local);
    W.swap(Wn);
    sweeps_step += 1.0;
    if (!(delta <= 2.0))
      error->all(FLERR, "Fix spin/collective: the spin fields are not finite at step {}",
                 update->ntimestep);
    if (it > 1 && delta > 1e3 * tol && delta < previous) theta = delta / previous;
    if (delta <= tol || (theta < 0.5 && delta * theta <= tol * (1.0 - theta))) break;
    if (it > 1 && delta <= floor_tol && delta >= previous) break;    // round-off
    if (it == max_iter)
      error->all(FLERR, "Fix spin/collective: the midpoint spins did not converge in {} "
                        "sweeps at step {} (max change {:.3g}); reduce the timestep",
                 max_iter, update->ntimestep, delta);
    previous = delta;
  }
  double far = 0.0;
  for (int k = 0; k < 3 * n; k++) far = std::max(far, std::fabs(W[k] - W_start[k]));
  moved = global_max(far);
}

/* One second-order step of size h (the class comment). */
void FixSpinCollective::substep(double h)
{
  const int n = atom->nlocal;
  double **x = atom->x;
  double **v = atom->v;
  double **sp = atom->sp;
  const double *rmass = atom->rmass;
  const double *mass = atom->mass;
  const int *type = atom->type;
  const size_t n3 = 3 * static_cast<size_t>(n);
  for (auto arr : {&q0, &v0, &s0, &qt, &qt_last, &P, &W, &Wn, &F, &Ba, &Bb}) arr->resize(n3);
  for (int i = 0; i < n; i++)
    for (int d = 0; d < 3; d++) {
      q0[3 * i + d] = x[i][d];
      v0[3 * i + d] = v[i][d];
      s0[3 * i + d] = sp[i][d];
    }
  for (int i = 0; i < n; i++)
    if (sp[i][3] != 0.0) predict(i, &s0[3 * i], &W[3 * i]);
    else for (int d = 0; d < 3; d++) W[3 * i + d] = s0[3 * i + d];
  std::vector<double> half_kick(n);    // (h/2) ftm2v / m_i
  for (int i = 0; i < n; i++)
    half_kick[i] = 0.5 * h * force->ftm2v / (rmass ? rmass[i] : mass[type[i]]);

  if (!moving) {
    double moved;
    solve(h, false, moved);
    rounds_step += 1.0;
  } else {
    bool settled = false;
    double qtol = 0.0;
    for (int round = 0; round < MAX_ROUNDS && !settled; round++) {
      rounds_step += 1.0;
      put_state(q0, W);
      forces(F);
      double apart = 0.0, largest = 0.0;
      for (size_t k = 0; k < n3; k++) {
        P[k] = v0[k] + half_kick[k / 3] * F[k];
        qt[k] = q0[k] + h * P[k];
        largest = std::max(largest, std::fabs(qt[k]));
        if (round) apart = std::max(apart, std::fabs(qt[k] - qt_last[k]));
      }
      if (round == 0) {
        // ase_spin.md.policy.settled_qtol: round-off of the coordinates
        qtol = 4.0 * DBL_EPSILON * std::max(1.0, global_max(largest));
      } else if (global_max(apart) <= qtol) {
        break;    // q~ settled: W was solved at (the same) q~
      }
      double moved;
      solve(h, true, moved);
      qt_last = qt;
      settled = moved <= settled_tol;
      if (round == MAX_ROUNDS - 1 && !settled)
        error->all(FLERR, "Fix spin/collective: positions and midpoint spins did not settle "
                          "in {} rounds at step {}; reduce the timestep",
                   MAX_ROUNDS, update->ntimestep);
    }
    // end forces F(q~, W), the second half kick
    put_state(qt, W);
    forces(F);
    for (size_t k = 0; k < n3; k++) P[k] += half_kick[k / 3] * F[k];
  }

  record();
  // the end spins: the reflection of s about W, s~ = s + 2 (s x W) x W
  for (int i = 0; i < n; i++) {
    const double *s = &s0[3 * i];
    const double *w = &W[3 * i];
    if (sp[i][3] == 0.0) continue;
    const double u[3] = {s[1] * w[2] - s[2] * w[1], s[2] * w[0] - s[0] * w[2],
                         s[0] * w[1] - s[1] * w[0]};
    sp[i][0] = s[0] + 2.0 * (u[1] * w[2] - u[2] * w[1]);
    sp[i][1] = s[1] + 2.0 * (u[2] * w[0] - u[0] * w[2]);
    sp[i][2] = s[2] + 2.0 * (u[0] * w[1] - u[1] * w[0]);
  }
  for (int i = 0; i < n; i++)
    for (int d = 0; d < 3; d++) {
      if (moving) {
        x[i][d] = qt[3 * i + d];
        v[i][d] = P[3 * i + d];
      } else {
        x[i][d] = q0[3 * i + d];
      }
    }
  // the ghosts follow (the next substep's first evaluation, or LAMMPS's own
  // forward communication or re-neighbouring after this fix)
  forward();
}

/* f_ID[1]: midpoint sweeps in the last step (all stages); [2]: outer rounds in the last
   step; [3]: sweeps since the fix was defined; [4], [5], [6]: forward and reverse
   ghost exchanges and global reductions (MPI_Allreduce) the fix made in the last
   step (LAMMPS's own once-a-step exchanges not counted); [7]: ghost atoms, the
   largest number on a rank (atom_style spin moves 7 doubles a ghost forward: x,
   sp; 9 in reverse: f, fm, fm_long). The same on every rank. */
double FixSpinCollective::compute_vector(int k)
{
  if (k == 0) return sweeps_step;
  if (k == 1) return rounds_step;
  if (k == 2) return sweeps_total;
  if (k == 3) return forward_step;
  if (k == 4) return reverse_step;
  if (k == 5) return reduce_step;
  double ghosts = atom->nghost, most;
  MPI_Allreduce(&ghosts, &most, 1, MPI_DOUBLE, MPI_MAX, world);
  return most;
}
