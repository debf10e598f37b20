/* fix spin/collective: the collective symplectic PRK step of ase_spin
   (Störmer–Verlet for the atoms, the spherical midpoint method for the spins)
   as a LAMMPS fix, loaded as a plugin.

   Part of the ase_spin LAMMPS plugin. Copyright (C) 2025 the ase_spin authors.

   This program is free software; you can redistribute it and/or modify it
   under the terms of the GNU General Public License as published by the Free
   Software Foundation; either version 2 of the License, or (at your option)
   any later version. It links against LAMMPS (GPL-2) and is a derivative work
   of it; see LICENSE in this folder. The ase_spin Python package around it is
   MIT licensed. */

#ifdef FIX_CLASS
// clang-format off
FixStyle(spin/collective,FixSpinCollective);
// clang-format on
#else

#ifndef ASE_SPIN_FIX_SPIN_COLLECTIVE_H
#define ASE_SPIN_FIX_SPIN_COLLECTIVE_H

#include "fix.h"

#include <string>
#include <vector>

namespace LAMMPS_NS {

class FixSpinCollective : public Fix {
 public:
  FixSpinCollective(class LAMMPS *, int, char **);
  ~FixSpinCollective() override;
  int setmask() override;
  void post_constructor() override;
  void init() override;
  void initial_integrate(int) override;
  double compute_vector(int) override;
  void grow_arrays(int) override;
  void copy_arrays(int, int, int) override;
  void set_arrays(int) override;
  int pack_exchange(int, double *) override;
  int unpack_exchange(int, double *) override;
  double memory_usage() override;

 private:
  int moving;                 // 1: lattice moving, 0: frozen
  std::vector<double> gammas; // stages of the composition (sum 1)
  double tol, floor_tol, settled_tol;
  int max_iter;
  std::string carrier_id;     // the nve/spin fix that switches on the lattice forces
  std::vector<class Pair *> spin_pairs, first_pairs;
  std::vector<Fix *> field_fixes;
  bool initialised;

  // per atom, migrating with it (grow/copy/pack_exchange): the number of steps
  // recorded (up to depth), then per stage the increments W - s of the last depth
  // steps, the newest first
  double **history;
  int depth, history_width;
  int stage;    // the composition stage being taken

  // per-atom work arrays (local atoms, 3 per atom)
  std::vector<double> q0, v0, s0, qt, qt_last, P, W, Wn, F, Ba, Bb;
  double sweeps_step, rounds_step, sweeps_total;
  // communication in the last step (all stages): forward and reverse ghost
  // exchanges and global reductions the fix itself made
  double forward_step, reverse_step, reduce_step;

  void substep(double h);
  void predict(int i, const double *s, double *w) const;
  void record();
  void solve(double h, bool mean, double &moved);
  void put_state(const std::vector<double> &pos, const std::vector<double> &spins);
  void fields(std::vector<double> &out);
  void forces(std::vector<double> &out);
  double global_max(double value);
  void forward();
  void reverse();
};

}    // namespace LAMMPS_NS

#endif
#endif
