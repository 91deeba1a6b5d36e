/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/indent — a rigid sphere pressed on a part ([[indenter]], beyond
   the paper; docs/calibration.md "Contact").

     fix ID GROUP rs/indent X Y Z R TX TY TZ N stiffness K|d_NAME

   Each particle p of GROUP that the sphere's surface reaches is pushed radially out with
   the linear penalty of the operator Indent (model/operators.py):

     a_p = k_p·g_p·(p − c)/‖p − c‖,   g_p = R + r_p − ‖p − c‖ > 0,

   r_p the particle's radius (d_rsr), k_p its stiffness per unit mass (K, or the per-atom
   property d_NAME; 0: not pushed), added as the force m·a. The centre c moves linearly from
   (X, Y, Z) by (TX, TY, TZ) over the first N timesteps and then stays: c = c0 + f·T with
   f = min(step/N, 1) at timestep `step` (N = 0: f = 1 from the start), so the forces of the
   state after n steps use the centre of step n, as the reference engine does. Owned atoms
   only: no ghosts, no communication. The fix's global vector is the sphere's total force on
   the group (1–3) and the particles it pushes (4), summed over the ranks (fix_modify-free
   thermo output: f_ID[1] ...).
------------------------------------------------------------------------- */

#include "fix_rs_indent.h"

#include "atom.h"
#include "error.h"
#include "update.h"
#include "utils.h"

#include <cmath>
#include <cstring>

using namespace LAMMPS_NS;
using namespace FixConst;

FixRSIndent::FixRSIndent(LAMMPS *lmp, int narg, char **arg) :
    Fix(lmp, narg, arg), kconst(0.0), summed(false)
{
  const char *usage = "Illegal fix rs/indent command: fix ID GROUP rs/indent X Y Z R TX TY TZ N "
                      "stiffness K|d_NAME";
  if (narg != 13 || strcmp(arg[11], "stiffness") != 0) error->all(FLERR, usage);
  const char *names[3] = {"X", "Y", "Z"};
  for (int d = 0; d < 3; d++) {
    c0[d] = utils::numeric(FLERR, arg[3 + d], false, lmp);
    travel[d] = utils::numeric(FLERR, arg[7 + d], false, lmp);
    if (!std::isfinite(c0[d]) || !std::isfinite(travel[d]))
      error->all(FLERR, "Fix rs/indent: centre {} and travel T{} must be finite, got {} and {}",
                 names[d], names[d], arg[3 + d], arg[7 + d]);
  }
  radius = utils::numeric(FLERR, arg[6], false, lmp);
  if (!(radius > 0.0) || !std::isfinite(radius))
    error->all(FLERR, "Fix rs/indent: the sphere's radius R must be positive, got {}", arg[6]);
  nsteps = utils::bnumeric(FLERR, arg[10], false, lmp);
  if (nsteps < 0) error->all(FLERR, "Fix rs/indent: steps N must be >= 0, got {}", arg[10]);
  if (strncmp(arg[12], "d_", 2) == 0) {
    kname = arg[12] + 2;
  } else {
    kconst = utils::numeric(FLERR, arg[12], false, lmp);
    if (!(kconst >= 0.0) || !std::isfinite(kconst))
      error->all(FLERR, "Fix rs/indent: stiffness must be >= 0 or a per-atom d_NAME, got {}",
                 arg[12]);
  }
  vector_flag = 1;
  size_vector = 4;
  global_freq = 1;
  extvector = 0;
  for (int k = 0; k < 4; k++) ftotal[k] = fall[k] = 0.0;
}

int FixRSIndent::setmask()
{
  return POST_FORCE | MIN_POST_FORCE;
}

void FixRSIndent::init()
{
  RackStress::radii(atom, error, "rs/indent");
  if (!kname.empty()) {
    int flag, cols;
    int idx = atom->find_custom(kname.c_str(), flag, cols);
    if (idx < 0 || flag != 1 || cols != 0)
      error->all(FLERR, "Fix rs/indent: stiffness d_{} is not a per-atom floating-point "
                 "property (fix property/atom d_{})", kname, kname);
  }
}

void FixRSIndent::setup(int vflag)
{
  post_force(vflag);
}

void FixRSIndent::min_setup(int vflag)
{
  post_force(vflag);
}

void FixRSIndent::min_post_force(int vflag)
{
  post_force(vflag);
}

void FixRSIndent::post_force(int /*vflag*/)
{
  double **x = atom->x;
  double **f = atom->f;
  int *mask = atom->mask;
  const int nlocal = atom->nlocal;
  const double *r = RackStress::radii(atom, error, "rs/indent");
  const double *kv = nullptr;
  if (!kname.empty()) {
    int flag, cols;
    kv = atom->dvector[atom->find_custom(kname.c_str(), flag, cols)];
  }
  // the centre at this timestep: Indent.centre_at's arithmetic
  const double s = (double) update->ntimestep;
  const double frac = (nsteps <= 0 || s >= (double) nsteps) ? 1.0 : s / (double) nsteps;
  double c[3];
  for (int d = 0; d < 3; d++) c[d] = c0[d] + frac * travel[d];
  for (int k = 0; k < 4; k++) ftotal[k] = 0.0;
  summed = false;
  for (int i = 0; i < nlocal; i++) {
    if (!(mask[i] & groupbit)) continue;
    const double k = kv ? kv[i] : kconst;
    if (!(k > 0.0)) continue;
    const double d0 = x[i][0] - c[0], d1 = x[i][1] - c[1], d2 = x[i][2] - c[2];
    const double dist = std::sqrt(d0 * d0 + d1 * d1 + d2 * d2);
    const double g = (radius + r[i]) - dist;
    if (!(g > 0.0)) continue;
    const double w = k * g / dist;
    const double m = RackStress::mass(atom, i);
    const double a[3] = {w * d0, w * d1, w * d2};
    for (int d = 0; d < 3; d++) {
      f[i][d] += m * a[d];
      ftotal[d] += m * a[d];
    }
    ftotal[3] += 1.0;
  }
}

double FixRSIndent::compute_vector(int n)
{
  if (!summed) {
    MPI_Allreduce(ftotal, fall, 4, MPI_DOUBLE, MPI_SUM, world);
    summed = true;
  }
  return fall[n];
}
