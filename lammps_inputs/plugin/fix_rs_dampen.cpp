/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/dampen — dampen, Eq. 9, and conditional dampen, Eq. 28.

     fix ID TARGET rs/dampen c [type T c_T ...] [contact GROUP]

   Without contact: Eq. 9's −c·v on every target particle (the force −c·m·v), with c_T in place
   of c on atoms of type T: what LAMMPS' fix viscous does with γ = c·m, over the rows a moving
   group holds (rs_common.h, "Resting atoms") rather than over every owned atom.

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
    Fix(lmp, narg, arg), contactbit(0), built(false), ready(false), holds(true)
{
  const char *usage = "Illegal fix rs/dampen command: fix ID TARGET rs/dampen c [type T c_T ...] "
                      "[contact GROUP]";
  if (narg < 4) error->all(FLERR, usage);
  c = utils::numeric(FLERR, arg[3], false, lmp);
  if (!std::isfinite(c)) error->all(FLERR, "Fix rs/dampen: coefficient c must be finite, got {}", arg[3]);
  ctype.assign(atom->ntypes + 1, c);
  for (int k = 4; k < narg;) {
    if (strcmp(arg[k], "type") == 0 && k + 2 < narg) {
      int t = utils::inumeric(FLERR, arg[k + 1], false, lmp);
      if (t < 1 || t > atom->ntypes)
        error->all(FLERR, "Fix rs/dampen: type {} is not an atom type (1..{})", t, atom->ntypes);
      ctype[t] = utils::numeric(FLERR, arg[k + 2], false, lmp);
      if (!std::isfinite(ctype[t]))
        error->all(FLERR, "Fix rs/dampen: coefficient of type {} must be finite, got {}", t, arg[k + 2]);
      k += 3;
    } else if (strcmp(arg[k], "contact") == 0 && k + 2 == narg) {
      contactbit = RackStress::groupbit(group, error, "rs/dampen", "contact", arg[k + 1]);
      holds = false;
      k += 2;
    } else
      error->all(FLERR, usage);
  }
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
  if (contactbit) RackStress::radii(atom, error, "rs/dampen");
}

void FixRSDampen::setup(int vflag)
{
  built = false;
  first_rows = RackStress::in_first(lmp, groupbit);
  if (!ready && contactbit) RackStress::enroll(lmp, this);
  ready = true;
  RackStress::invalidate(lmp);
  post_force(vflag);
}

/* whether one of this rank's targets overlaps a GROUP particle (summed over the ranks) */
void FixRSDampen::partial(double *flag)
{
  double *r = RackStress::radii(atom, error, "rs/dampen");
  if (!built || neighbor->ago == 0) {
    list.build(lmp, groupbit, contactbit, r, 0, !built);
    built = true;
  }
  // the candidates that can touch before any of them moves a skin/8 (rs_common.h, Contacts)
  list.refresh(lmp, r, 0.25 * neighbor->skin);
  double **x = atom->x;
  for (size_t q = 0; q < list.near_rows.size(); q++) {
    int i = list.rows[list.near_rows[q]];
    for (int n = list.near_first[q]; n < list.near_first[q + 1]; n++) {
      int j = list.near_partner[n];
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
  if (contactbit) RackStress::reduce_sums(lmp);    // the condition, fused with the step's other sums
  if (!holds) return;
  const int n = RackStress::extent(atom, first_rows);    // the moving rows, where they hold all
  if (n == 0) return;
  const double *__restrict v = atom->v[0];
  double *__restrict f = atom->f[0];
  const int *__restrict mask = atom->mask, *__restrict type = atom->type;
  if (atom->rmass) {
    for (int i = 0; i < n; i++)
      if (mask[i] & groupbit) {
        double g = ctype[type[i]] * atom->rmass[i];
        for (int e = 0; e < 3; e++) f[3 * i + e] -= g * v[3 * i + e];
      }
    return;
  }
  // γ = c_T·m_T of each type (the same product the per-atom one was)
  gtype.resize(ctype.size());
  for (size_t t = 1; t < ctype.size(); t++) gtype[t] = ctype[t] * atom->mass[t];
  const double *__restrict G = gtype.data();
  for (int i = 0; i < n; i++)
    if (mask[i] & groupbit) {
      const double g = G[type[i]];
      for (int e = 0; e < 3; e++) f[3 * i + e] -= g * v[3 * i + e];
    }
}
