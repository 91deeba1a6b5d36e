/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/dampen — conditional dampen, Eq. 28.

     fix ID TARGET rs/dampen c contact GROUP

   Eq. 28's dampen(10 + 85⟨the leg touches the sediment⟩): the base coefficient is LAMMPS' own
   fix viscous; this fix adds Eq. 9's −c·v on every target particle while the contact condition
   of Eq. 4 holds: some particle p of TARGET overlaps some particle u of GROUP,
   ‖u − p‖ < r_p + r_u (Eq. 10's support). The condition is one fact for the whole group: each
   rank tests its owned targets, one MPI_Allreduce (a sum, fused with the step's other sums,
   rs_common.h) decides. A phase condition on the same
   operator is the deck's: the fix exists only in the phases where it holds.
------------------------------------------------------------------------- */

#include "fix_rs_dampen.h"

#include "atom.h"
#include "error.h"
#include "neighbor.h"
#include "utils.h"

#include <cmath>
#include <cstring>

using namespace LAMMPS_NS;
using namespace FixConst;

FixRSDampen::FixRSDampen(LAMMPS *lmp, int narg, char **arg) :
    Fix(lmp, narg, arg), built(false), ready(false), holds(false)
{
  if (narg != 6 || strcmp(arg[4], "contact") != 0)
    error->all(FLERR, "Illegal fix rs/dampen command: fix ID TARGET rs/dampen c contact GROUP");
  c = utils::numeric(FLERR, arg[3], false, lmp);
  if (!std::isfinite(c)) error->all(FLERR, "Fix rs/dampen: coefficient c must be finite, got {}", arg[3]);
  contactbit = RackStress::groupbit(group, error, "rs/dampen", "contact", arg[5]);
}

FixRSDampen::~FixRSDampen()
{
  RackStress::leave(lmp, this);
}

int FixRSDampen::setmask()
{
  return POST_FORCE;
}

void FixRSDampen::init()
{
  RackStress::radii(atom, error, "rs/dampen");
}

void FixRSDampen::setup(int vflag)
{
  built = false;
  if (!ready) RackStress::enroll(lmp, this);
  ready = true;
  RackStress::invalidate(lmp);
  post_force(vflag);
}

/* whether one of this rank's targets overlaps a GROUP particle (summed over the ranks) */
void FixRSDampen::partial(double *flag)
{
  double *r = RackStress::radii(atom, error, "rs/dampen");
  if (!built || neighbor->ago == 0) {
    list.build(lmp, groupbit, contactbit, r);
    built = true;
  }
  double **x = atom->x;
  for (size_t k = 0; k < list.rows.size(); k++) {
    int i = list.rows[k];
    for (int n = list.first[k]; n < list.first[k + 1]; n++) {
      int j = list.partner[n];
      double d2 = 0.0;
      for (int e = 0; e < 3; e++) {
        double d = x[j][e] - x[i][e];
        d2 += d * d;
      }
      double R = r[i] + r[j];
      if (d2 < R * R) {
        flag[0] = 1.0;
        return;
      }
    }
  }
}

void FixRSDampen::total(const double *flag)
{
  holds = flag[0] > 0.0;
}

void FixRSDampen::post_force(int /*vflag*/)
{
  RackStress::reduce_sums(lmp);     // the condition, fused with the step's other sums
  if (!holds) return;
  double **v = atom->v, **f = atom->f;
  int *mask = atom->mask;
  for (int i = 0; i < atom->nlocal; i++)
    if (mask[i] & groupbit) {
      double g = c * RackStress::mass(atom, i);
      for (int e = 0; e < 3; e++) f[i][e] -= g * v[i][e];
    }
}
