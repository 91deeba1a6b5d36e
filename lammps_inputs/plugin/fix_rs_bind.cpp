/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/bind — directed bind with a per-pair L0, Eqs. 12–13.

     fix ID TARGET rs/bind SOURCE c btype N

   bind(u, ĉ) (Eq. 13) over the pairs of a coefficient matrix such as within(d) (Eq. 16): the
   pairs are the data file's bonds of type N (one bond per unordered pair, carried by LAMMPS
   with their atoms: bond_style zero, newton_bond off, so each rank lists every bond of the atoms
   it owns). On each target particle p of a pair, from its source partner u, Eq. 12:

     c·(u − p)·(1 − L0²/‖u − p‖²),   L0 = ‖u_o − p_o‖ per pair (original positions d2_rso)

   LAMMPS bond styles keep r0 per bond type; here every pair has its own L0. Directed: this fix
   adds only the acceleration on TARGET from SOURCE; the reverse is its own fix (and one fix does
   both ends when a group is bound to itself, where ĉ holds (i, j) and (j, i)).
------------------------------------------------------------------------- */

#include "fix_rs_bind.h"

#include "atom.h"
#include "error.h"
#include "force.h"
#include "neighbor.h"
#include "utils.h"

#include <cmath>
#include <cstring>

using namespace LAMMPS_NS;
using namespace FixConst;

FixRSBind::FixRSBind(LAMMPS *lmp, int narg, char **arg) : Fix(lmp, narg, arg)
{
  if (narg != 7 || strcmp(arg[5], "btype") != 0)
    error->all(FLERR, "Illegal fix rs/bind command: fix ID TARGET rs/bind SOURCE c btype N");
  sourcebit = RackStress::groupbit(group, error, "rs/bind", "source", arg[3]);
  c = utils::numeric(FLERR, arg[4], false, lmp);
  if (!std::isfinite(c)) error->all(FLERR, "Fix rs/bind: coefficient c must be finite, got {}", arg[4]);
  btype = utils::inumeric(FLERR, arg[6], false, lmp);
  if (btype < 1 || btype > atom->nbondtypes)
    error->all(FLERR, "Fix rs/bind: btype {} is not a bond type (1..{})", btype, atom->nbondtypes);
}

int FixRSBind::setmask()
{
  return POST_FORCE;
}

void FixRSBind::init()
{
  RackStress::originals(atom, error, "rs/bind");
  if (force->newton_bond)
    error->all(FLERR, "Fix rs/bind needs newton_bond off ('newton on off' before read_data): "
               "each rank must list every bond of the atoms it owns");
}

void FixRSBind::setup(int vflag)
{
  post_force(vflag);
}

void FixRSBind::post_force(int /*vflag*/)
{
  double **x = atom->x, **f = atom->f, **o = RackStress::originals(atom, error, "rs/bind");
  int *mask = atom->mask;
  int nlocal = atom->nlocal;
  int **bondlist = neighbor->bondlist;
  int nbondlist = neighbor->nbondlist;

  for (int n = 0; n < nbondlist; n++) {
    if (bondlist[n][2] != btype) continue;
    int i1 = bondlist[n][0], i2 = bondlist[n][1];
    double d[3], q = 0.0, d2 = 0.0;
    for (int e = 0; e < 3; e++) {
      d[e] = x[i2][e] - x[i1][e];
      double l = o[i2][e] - o[i1][e];
      q += l * l;
      d2 += d[e] * d[e];
    }
    double s = c * (1.0 - q / d2);
    if (i1 < nlocal && (mask[i1] & groupbit) && (mask[i2] & sourcebit)) {
      double m = RackStress::mass(atom, i1);
      for (int e = 0; e < 3; e++) f[i1][e] += m * (s * d[e]);
    }
    if (i2 < nlocal && (mask[i2] & groupbit) && (mask[i1] & sourcebit)) {
      double m = RackStress::mass(atom, i2);
      for (int e = 0; e < 3; e++) f[i2][e] -= m * (s * d[e]);
    }
  }
}
