/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/force — a constant force, Eq. 8.

     fix ID GROUP rs/force Fx Fy Fz

   force(â) (Eq. 8) on every particle of GROUP as the force F = m·â the deck computes: the
   arithmetic of LAMMPS' fix addforce with constant values (f += F), over the rows a moving
   group holds (rs_common.h, "Resting atoms") rather than over every owned atom, so a scene
   with a million resting particles pays for the ones that move.
------------------------------------------------------------------------- */

#include "fix_rs_force.h"

#include "atom.h"
#include "error.h"
#include "utils.h"

#include <cmath>

using namespace LAMMPS_NS;
using namespace FixConst;

FixRSForce::FixRSForce(LAMMPS *lmp, int narg, char **arg) : Fix(lmp, narg, arg)
{
  if (narg != 6) error->all(FLERR, "Illegal fix rs/force command: fix ID GROUP rs/force Fx Fy Fz");
  for (int d = 0; d < 3; d++) {
    fv[d] = utils::numeric(FLERR, arg[3 + d], false, lmp);
    if (!std::isfinite(fv[d]))
      error->all(FLERR, "Fix rs/force: force component {} must be finite, got {}", d + 1, arg[3 + d]);
  }
}

int FixRSForce::setmask()
{
  return POST_FORCE;
}

void FixRSForce::setup(int vflag)
{
  first_rows = RackStress::in_first(lmp, groupbit);
  post_force(vflag);
}

void FixRSForce::post_force(int /*vflag*/)
{
  double **f = atom->f;
  int *mask = atom->mask;
  const int n = RackStress::extent(atom, first_rows);
  for (int i = 0; i < n; i++)
    if (mask[i] & groupbit) {
      f[i][0] += fv[0];
      f[i][1] += fv[1];
      f[i][2] += fv[2];
    }
}
