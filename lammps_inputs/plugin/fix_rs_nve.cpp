/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/nve — integrate, Eq. 5, as LAMMPS' fix nve does it.

     fix ID GROUP rs/nve

   The arithmetic of LAMMPS' fix nve (velocity Verlet: v += dt/2·f/m, x += dt·v, then
   v += dt/2·f/m with the new forces), so a trajectory is the same to the bit, over the rows a
   moving group holds (rs_common.h, "Resting atoms"). What differs is the cost: fix nve divides
   dt/2 by the mass of every atom twice a step; here dt/(2m) is taken once per atom type at
   each setup (the same division, so the same value), and the loop runs over plain arrays.

   It also does LAMMPS' displacement check for a deck that hands it over (`neigh_modify delay 0
   every 1 check no once yes`): in post_integrate, before LAMMPS decides whether to reneighbour,
   whether a row it integrates has moved more than half the skin since the last reneighbouring
   (Neighbor::check_distance's test), carried in the plugin's reduction of the step's gathered
   positions (rs_common.h) — one collective a step where LAMMPS' check and that reduction were
   two. If any rank's has, the fix forces the reneighbouring at this step (next_reneighbor),
   as LAMMPS' own check would have.
------------------------------------------------------------------------- */

#include "fix_rs_nve.h"

#include "atom.h"
#include "domain.h"
#include "error.h"
#include "force.h"
#include "modify.h"
#include "neighbor.h"
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
  force_reneighbor = 1;
  next_reneighbor = -1;
}

int FixRSNVE::setmask()
{
  return INITIAL_INTEGRATE | POST_INTEGRATE | PRE_NEIGHBOR | FINAL_INTEGRATE;
}

void FixRSNVE::init()
{
  if (utils::strmatch(update->integrate_style, "^respa"))
    error->all(FLERR, "Fix rs/nve: not for run_style respa (use fix nve)");
  // the deck's `neigh_modify ... once yes` leaves the displacement check to this fix
  check = neighbor->build_once != 0;
  if (check) {
    if (modify->get_fix_by_style("^rs/nve$").size() > 1)
      error->all(FLERR, "Fix rs/nve: with neigh_modify once yes only one rs/nve fix can check "
                 "displacements (fix {} is the second)", id);
    if (domain->box_change && (domain->xperiodic || domain->yperiodic || domain->zperiodic))
      error->all(FLERR, "Fix rs/nve: the displacement check does not follow a periodic box "
                 "that changes: use neigh_modify check yes once no");
  }
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
  RackStress::invalidate(lmp);
}

/* the positions of the first n owned rows at a reneighbouring (Neighbor::build's xhold) */
void FixRSNVE::hold(int n)
{
  if (!check) return;
  xhold.assign(atom->x[0], atom->x[0] + 3 * n);
}

/* a setup reneighbours before setup() knows the rows this fix integrates: every owned row */
void FixRSNVE::setup_pre_neighbor()
{
  hold(atom->nlocal);
}

void FixRSNVE::pre_neighbor()
{
  hold(RackStress::extent(atom, first_rows));
}

/* LAMMPS' displacement check over the rows this fix moves (the others keep the positions of the
   last reneighbouring), carried by the plugin's position reduction (module doc) */
void FixRSNVE::post_integrate()
{
  if (!check) return;
  const int n = RackStress::extent(atom, first_rows);
  const double trigger = 0.25 * neighbor->skin * neighbor->skin;
  int moved = 3 * (size_t) n > xhold.size();    // rows past the held ones: reneighbour
  const double *__restrict x = atom->x[0];
  const double *__restrict h = xhold.data();
  for (int i = 0; i < n && !moved; i++) {
    const double dx = x[3 * i] - h[3 * i], dy = x[3 * i + 1] - h[3 * i + 1],
                 dz = x[3 * i + 2] - h[3 * i + 2];
    if (dx * dx + dy * dy + dz * dz > trigger) moved = 1;
  }
  if (RackStress::reduce_positions(lmp, moved)) next_reneighbor = update->ntimestep;
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
