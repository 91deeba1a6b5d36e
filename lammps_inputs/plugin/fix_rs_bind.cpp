/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/bind — directed bind with a per-pair L0, Eqs. 12–13.

     fix ID TARGET rs/bind SOURCE c btype N

   bind(u, ĉ) (Eq. 13) over the pairs of a coefficient matrix such as within(d) (Eq. 16): the
   pairs are the data file's bonds of type N (one bond per unordered pair, carried by LAMMPS
   with their atoms: bond_style zero, newton_bond off, so every atom stores each of its bonds). On each target particle p of a pair, from its source partner u, Eq. 12:

     c·(u − p)·(1 − L0²/‖u − p‖²),   L0 = ‖u_o − p_o‖ per pair (original positions d2_rso)

   LAMMPS bond styles keep r0 per bond type; here every pair has its own L0. Directed: this fix
   adds only the acceleration on TARGET from SOURCE; the reverse is its own fix (and one fix does
   both ends when a group is bound to itself, where ĉ holds (i, j) and (j, i)).
------------------------------------------------------------------------- */

#include "fix_rs_bind.h"

#include "atom.h"
#include "domain.h"
#include "error.h"
#include "force.h"
#include "neighbor.h"
#include "utils.h"

#include <algorithm>
#include <cmath>
#include <cstring>

using namespace LAMMPS_NS;
using namespace FixConst;

FixRSBind::FixRSBind(LAMMPS *lmp, int narg, char **arg) : Fix(lmp, narg, arg), built(false)
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
  built = false;
  post_force(vflag);
}

/* this rank's pairs of bond type btype, listed again whenever LAMMPS reneighbours: L0² per pair
   from the original positions, and the ends this fix acts on (an owned target with a source
   partner). Each pair is listed once, by its owned end with the smaller atom id (or by its
   owned end when the other is a ghost), the listing atoms taken in atom-id order and each
   one's bonds in its own order (the data file's, which an atom keeps through exchanges and a
   restart). An atom then adds its terms in an order that depends only on which atoms this
   rank owns, not on the rows LAMMPS gave them (exchanges, active-only reordering, a resumed
   run's data file order): a resumed run under MPI is bit for bit the uninterrupted one.
   (LAMMPS' own bond list follows the rows.) */
void FixRSBind::collect()
{
  double **o = RackStress::originals(atom, error, "rs/bind");
  int *mask = atom->mask;
  int nlocal = atom->nlocal;
  tagint *tag = atom->tag;
  int *num_bond = atom->num_bond;
  int **bond_type = atom->bond_type;
  tagint **bond_atom = atom->bond_atom;
  int either = groupbit | sourcebit;
  // the listing atoms in atom-id order (rs_common.h)
  auto lists = [&](int i) { return num_bond[i] && (mask[i] & either); };
  listers.clear();
  for (int i = 0; i < nlocal; i++)
    if (lists(i)) listers.push_back(i);
  RackStress::in_id_order(atom, nlocal, listers, lists);
  p1.clear();
  p2.clear();
  ends.clear();
  q.clear();
  for (int i1 : listers) {
    for (int m = 0; m < num_bond[i1]; m++) {
      if (bond_type[i1][m] != btype) continue;
      int i2 = atom->map(bond_atom[i1][m]);
      if (i2 < 0) continue;    // not present: LAMMPS' own bond list stops the run ("missing")
      i2 = domain->closest_image(i1, i2);
      if (i2 < nlocal && tag[i2] < tag[i1]) continue;    // listed by its other owned end
      int e = 0;
      if ((mask[i1] & groupbit) && (mask[i2] & sourcebit)) e |= 1;
      if (i2 < nlocal && (mask[i2] & groupbit) && (mask[i1] & sourcebit)) e |= 2;
      if (!e) continue;
      double l2 = 0.0;
      for (int k = 0; k < 3; k++) {
        double l = o[i2][k] - o[i1][k];
        l2 += l * l;
      }
      p1.push_back(i1);
      p2.push_back(i2);
      ends.push_back(e);
      q.push_back(l2);
    }
  }
  built = true;
}

void FixRSBind::post_force(int /*vflag*/)
{
  if (!built || neighbor->ago == 0) collect();
  // LAMMPS' x and f are contiguous (3 doubles per row): read them without the row pointers
  const double *__restrict x = atom->x[0];
  double *__restrict f = atom->f[0];
  // unit masses (the paper's, and every generated deck's): f = a, the same bits as 1·a
  const bool unit = RackStress::unit_masses(atom);
  const int n = (int) p1.size();
  const int *__restrict P1 = p1.data(), *__restrict P2 = p2.data();
  const int *__restrict E = ends.data();
  const double *__restrict Q = q.data();
  for (int k = 0; k < n; k++) {
    const int i1 = P1[k], i2 = P2[k];
    const double *a = x + 3 * i1, *b = x + 3 * i2;
    const double dx = b[0] - a[0], dy = b[1] - a[1], dz = b[2] - a[2];
    const double d2 = dx * dx + dy * dy + dz * dz;
    const double s = RackStress::eq12(c, Q[k], d2);
    const double ax = s * dx, ay = s * dy, az = s * dz;
    if (!(std::isfinite(ax) && std::isfinite(ay) && std::isfinite(az))) {
      // a pair that coincides (d = 0): neither end gains it (rs_common.h, nonfinite)
      tagint *tag = atom->tag;
      tagint t = (E[k] & 1) ? tag[i1] : tag[i2];
      if (E[k] == 3) t = std::min(tag[i1], tag[i2]);
      RackStress::nonfinite(lmp, "rs/bind", t);
      continue;
    }
    if (E[k] & 1) {
      const double m = unit ? 1.0 : RackStress::mass(atom, i1);
      f[3 * i1] += m * ax;
      f[3 * i1 + 1] += m * ay;
      f[3 * i1 + 2] += m * az;
    }
    if (E[k] & 2) {
      const double m = unit ? 1.0 : RackStress::mass(atom, i2);
      f[3 * i2] -= m * ax;
      f[3 * i2 + 1] -= m * ay;
      f[3 * i2 + 2] -= m * az;
    }
  }
}
