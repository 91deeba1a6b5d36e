/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/collide — directed collide, Eqs. 10–11.

     fix ID TARGET rs/collide SOURCE c [friction MU ETA] [activate MOVING]

   On each target particle p, from every source particle u that overlaps it (Eq. 11), Eq. 10
   with the reach the paper's prose gives (R = r_p + r_u, docs/model.md erratum 1):

     c·(u − p)·min(0, 1 − R²/‖u − p‖²)

   Directed: only the target gains it (the reverse, if any, is its own fix with its own c), so a
   one-way or phase-conditioned collision is exact where a pair style (Newton's third law) is not.
   Candidates within r_p + r_max + skin are searched among owned and ghost atoms when LAMMPS
   reneighbours (rs_common.h, Contacts); each step measures those within r_p + r_u + skin/4
   (Contacts::refresh, taken again from the candidates when one of them has moved skin/8).
   Radii: per-atom d_rsr.

   friction MU ETA: the pair's regularized Coulomb friction, history-free (LAMMPS' pair
   gran/hooke, tangential linear_nohistory; rackstress Collide.friction), added on the target:

     −min(MU·a_n, ETA·‖v_t‖)·v_t/‖v_t‖,   a_n = c·(R² − d²)/d,

   v_t the tangential part of v_p − v_u; ETA = ζ/m_p, ζ the pair's tangential damping. It reads
   the partner's velocity: a ghost's needs comm_modify vel yes (checked at init).

   activate MOVING (active-only integration, docs/model.md "Active particles"): MOVING is the
   group `fix nve` integrates and `atom_modify first` keeps first in LAMMPS' arrays. A resting
   target particle (not in MOVING) within r_p + r_u + 2·skin of a source particle in MOVING is
   added to MOVING when LAMMPS reneighbours, so LAMMPS' next reneighbouring puts it among the
   integrated rows before anything can reach it. A force on a row LAMMPS does not integrate yet
   (only possible if an atom moved more than a skin between two reneighbourings) stops the run;
   at a setup (run 0) it is allowed: the deck's second run 0 reorders such rows first.
------------------------------------------------------------------------- */

#include "fix_rs_collide.h"

#include "atom.h"
#include "comm.h"
#include "error.h"
#include "neighbor.h"
#include "update.h"
#include "utils.h"

#include <cmath>
#include <cstring>

using namespace LAMMPS_NS;
using namespace FixConst;

/* the near pairs' margin s as a fraction of LAMMPS' skin (Contacts::refresh): a quarter
   measured fastest on MagPod against 1 (every candidate) and 0.1 (rebuilt too often) */
static constexpr double NEAR = 0.25;

FixRSCollide::FixRSCollide(LAMMPS *lmp, int narg, char **arg) :
    Fix(lmp, narg, arg), actbit(0), mu(0.0), eta(0.0), built(false), in_setup(false),
    touching(0)
{
  const char *usage = "Illegal fix rs/collide command: fix ID TARGET rs/collide SOURCE c "
                      "[friction MU ETA] [activate MOVING]";
  if (narg < 5) error->all(FLERR, usage);
  for (int k = 5; k < narg;) {
    if (strcmp(arg[k], "activate") == 0 && k + 1 < narg && !actbit) {
      actbit = RackStress::groupbit(group, error, "rs/collide", "activate", arg[k + 1]);
      k += 2;
    } else if (strcmp(arg[k], "friction") == 0 && k + 2 < narg && mu == 0.0) {
      mu = utils::numeric(FLERR, arg[k + 1], false, lmp);
      eta = utils::numeric(FLERR, arg[k + 2], false, lmp);
      if (!(std::isfinite(mu) && mu > 0.0 && std::isfinite(eta) && eta >= 0.0))
        error->all(FLERR, "Fix rs/collide: friction needs MU > 0 and ETA >= 0, got {} {}",
                   arg[k + 1], arg[k + 2]);
      k += 3;
    } else {
      error->all(FLERR, usage);
    }
  }
  sourcebit = RackStress::groupbit(group, error, "rs/collide", "source", arg[3]);
  c = utils::numeric(FLERR, arg[4], false, lmp);
  if (!std::isfinite(c)) error->all(FLERR, "Fix rs/collide: coefficient c must be finite, got {}", arg[4]);
}

int FixRSCollide::setmask()
{
  return POST_FORCE;
}

void FixRSCollide::init()
{
  RackStress::radii(atom, error, "rs/collide");
  if (mu > 0.0 && comm->nprocs > 1 && !comm->ghost_velocity)
    error->all(FLERR, "Fix rs/collide: friction reads the partners' velocities: the deck "
               "needs comm_modify vel yes");
}

void FixRSCollide::setup(int vflag)
{
  built = false;
  in_setup = true;
  post_force(vflag);
  in_setup = false;
}

void FixRSCollide::post_force(int /*vflag*/)
{
  double *r = RackStress::radii(atom, error, "rs/collide");
  if (!built || neighbor->ago == 0) {
    list.build(lmp, groupbit, sourcebit, r, actbit, !built);
    built = true;
  }
  // the candidates that can touch before any of them moves NEAR/2 (rs_common.h, Contacts)
  list.refresh(lmp, r, NEAR * neighbor->skin);
  double **x = atom->x, **f = atom->f, **v = atom->v;
  touching = 0;
  for (size_t q = 0; q < list.near_rows.size(); q++) {
    int i = list.rows[list.near_rows[q]];
    double a[3] = {0.0, 0.0, 0.0};
    bool any = false;
    for (int n = list.near_first[q]; n < list.near_first[q + 1]; n++) {
      int j = list.near_partner[n];
      double d[3], d2 = 0.0;
      for (int e = 0; e < 3; e++) {
        d[e] = x[j][e] - x[i][e];
        d2 += d[e] * d[e];
      }
      double R = r[i] + r[j], R2 = R * R;
      if (!(d2 < R2)) continue;    // Eq. 11: only overlapping pairs (Eq. 10 is zero beyond)
      double s = c * std::fmin(0.0, 1.0 - R2 / d2);
      if (mu > 0.0) {    // the pair's Coulomb friction (header), with Eq. 10's term
        double an = c * (R2 - d2) / std::sqrt(d2);
        double w[3], t[3];
        for (int e = 0; e < 3; e++) w[e] = v[i][e] - v[j][e];
        double pr = (w[0] * d[0] + w[1] * d[1] + w[2] * d[2]) / d2;
        for (int e = 0; e < 3; e++) t[e] = w[e] - pr * d[e];
        double vt = std::sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
        double lim = mu * an;
        double k = lim < eta * vt ? lim / vt : eta;
        for (int e = 0; e < 3; e++) a[e] += s * d[e] - k * t[e];
      } else {
        for (int e = 0; e < 3; e++) a[e] += s * d[e];
      }
      any = true;
    }
    if (!any) continue;
    if (!RackStress::finite3(a)) {    // coincides with a partner (d = 0): rs_common.h
      RackStress::nonfinite(lmp, "rs/collide", atom->tag[i]);
      continue;
    }
    touching = 1;
    if (actbit && !in_setup && atom->firstgroupname && i >= atom->nfirst)
      error->one(FLERR, "Fix rs/collide: resting particle (atom id {}) was touched at step {} before "
                 "LAMMPS integrated it: a particle moved more than the neighbour skin ({}) between "
                 "two reneighbourings, so the run could not stay exact; a smaller time step or "
                 "weaker coefficients keep Eq. 5 stable", (bigint) atom->tag[i],
                 (bigint) update->ntimestep, neighbor->skin);
    double m = RackStress::mass(atom, i);
    for (int e = 0; e < 3; e++) f[i][e] += m * a[e];
  }
}

/* whether one of this rank's target particles overlaps a source particle this step */
void *FixRSCollide::extract(const char *name, int &dim)
{
  dim = 0;
  if (strcmp(name, "touching") == 0) return &touching;
  return nullptr;
}
