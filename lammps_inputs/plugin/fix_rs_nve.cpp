/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/nve — integrate, Eq. 5, as LAMMPS' fix nve does it.

     fix ID GROUP rs/nve

   The arithmetic of LAMMPS' fix nve (velocity Verlet: v += dt/2·f/m, x += dt·v, then
   v += dt/2·f/m with the new forces), so a trajectory is the same to the bit, over the rows a
   moving group holds (rs_common.h, "Resting atoms"). What differs is the cost: fix nve divides
   dt/2 by the mass of every atom twice a step; here dt/(2m) is taken once per atom type at
   each setup (the same division, so the same value), and the loop runs over plain arrays.
------------------------------------------------------------------------- */

#include "fix_rs_nve.h"

#include "atom.h"
#include "error.h"
#include "force.h"
#include "update.h"
#include "utils.h"

#include <cstring>

using namespace LAMMPS_NS;
using namespace FixConst;

FixRSNVE::FixRSNVE(LAMMPS *lmp, int narg, char **arg) : Fix(lmp, narg, arg), dtv(0.0), dtf(0.0)
{
  if (narg != 3) error->all(FLERR, "Illegal fix rs/nve command: fix ID GROUP rs/nve");
  dynamic_group_allow = 1;
  time_integrate = 1;
}

int FixRSNVE::setmask()
{
  return INITIAL_INTEGRATE | FINAL_INTEGRATE;
}

void FixRSNVE::init()
{
  if (utils::strmatch(update->integrate_style, "^respa"))
    error->all(FLERR, "Fix rs/nve: not for run_style respa (use fix nve)");
  reset_dt();
}

void FixRSNVE::reset_dt()
{
  dtv = update->dt;
  dtf = 0.5 * update->dt * force->ftm2v;
  dtfm.assign(atom->ntypes + 1, 0.0);
  if (!atom->rmass)
    for (int t = 1; t <= atom->ntypes; t++) dtfm[t] = dtf / atom->mass[t];
}

void FixRSNVE::setup(int /*vflag*/)
{
  first_rows = RackStress::in_first(lmp, groupbit);
}

void FixRSNVE::initial_integrate(int /*vflag*/)
{
  const int n = RackStress::extent(atom, first_rows);
  if (n == 0) return;
  double *__restrict x = atom->x[0];
  double *__restrict v = atom->v[0];
  const double *__restrict f = atom->f[0];
  const int *__restrict mask = atom->mask;
  const int *__restrict type = atom->type;
  const double *rmass = atom->rmass;
  const double *m = dtfm.data();
  for (int i = 0; i < n; i++)
    if (mask[i] & groupbit) {
      const double h = rmass ? dtf / rmass[i] : m[type[i]];
      for (int e = 0; e < 3; e++) {
        v[3 * i + e] += h * f[3 * i + e];
        x[3 * i + e] += dtv * v[3 * i + e];
      }
    }
}

void FixRSNVE::final_integrate()
{
  const int n = RackStress::extent(atom, first_rows);
  if (n == 0) return;
  double *__restrict v = atom->v[0];
  const double *__restrict f = atom->f[0];
  const int *__restrict mask = atom->mask;
  const int *__restrict type = atom->type;
  const double *rmass = atom->rmass;
  const double *m = dtfm.data();
  for (int i = 0; i < n; i++)
    if (mask[i] & groupbit) {
      const double h = rmass ? dtf / rmass[i] : m[type[i]];
      for (int e = 0; e < 3; e++) v[3 * i + e] += h * f[3 * i + e];
    }
}
