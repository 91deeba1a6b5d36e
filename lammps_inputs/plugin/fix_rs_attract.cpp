/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/attract — attract with index-matched regions, Eqs. 14, 27–28.

     fix ID TARGET rs/attract SOURCE c TIDX SIDX

   On each target particle p, from every source particle u it is matched with, Eq. 14 (constant
   magnitude c per pair, docs/model.md erratum 2):

     c·(u − p)/‖u − p‖

   Matched (Eqs. 27–28): c⟨TIDX_p = SIDX_u ≠ 0⟩, with TIDX and SIDX per-atom integer properties
   (fix property/atom i_TIDX i_SIDX, from the data file); the deck names the phase's index (the
   active body region follows the gait). TIDX = SIDX = all: every pair (a constant ĉ = [c]).
   The matched source particles are a small set gathered on every rank each step (an
   MPI_Allreduce fused with the step's other gathers, rs_common.h), so the attraction needs no ghosts however far the two regions are apart.
------------------------------------------------------------------------- */

#include "fix_rs_attract.h"

#include "atom.h"
#include "error.h"
#include "utils.h"

#include <cmath>
#include <cstring>

using namespace LAMMPS_NS;
using namespace FixConst;

FixRSAttract::FixRSAttract(LAMMPS *lmp, int narg, char **arg) : Fix(lmp, narg, arg), ready(false)
{
  if (narg != 7)
    error->all(FLERR, "Illegal fix rs/attract command: fix ID TARGET rs/attract SOURCE c TIDX SIDX");
  sourcebit = RackStress::groupbit(group, error, "rs/attract", "source", arg[3]);
  c = utils::numeric(FLERR, arg[4], false, lmp);
  if (!std::isfinite(c)) error->all(FLERR, "Fix rs/attract: coefficient c must be finite, got {}", arg[4]);
  bool all_t = strcmp(arg[5], "all") == 0, all_s = strcmp(arg[6], "all") == 0;
  if (all_t != all_s)
    error->all(FLERR, "Fix rs/attract: TIDX and SIDX are both region indices or both 'all', got {} {}",
               arg[5], arg[6]);
  if (!all_t) {
    tname = arg[5];
    sname = arg[6];
  }
}

FixRSAttract::~FixRSAttract()
{
  RackStress::leave(lmp, this);
}

int FixRSAttract::setmask()
{
  return POST_FORCE;
}

void FixRSAttract::init()
{
  if (!tname.empty()) {
    RackStress::ivector(atom, error, "rs/attract", tname);
    RackStress::ivector(atom, error, "rs/attract", sname);
  }
}

void FixRSAttract::setup(int vflag)
{
  if (!ready) {
    const int *skey = tname.empty() ? nullptr : RackStress::ivector(atom, error, "rs/attract", sname);
    few.collect(lmp, sourcebit, skey);
    // members by region index, each list in atom-id order
    int maxkey = 0;
    for (int k = 0; k < few.size(); k++) maxkey = std::max(maxkey, few.key[k]);
    by_key_first.assign(maxkey + 2, 0);
    for (int k = 0; k < few.size(); k++) by_key_first[few.key[k] + 1]++;
    for (int v = 0; v <= maxkey; v++) by_key_first[v + 1] += by_key_first[v];
    by_key.assign(few.size(), 0);
    std::vector<int> fill(by_key_first.begin(), by_key_first.end() - 1);
    for (int k = 0; k < few.size(); k++) by_key[fill[few.key[k]]++] = k;
    RackStress::enroll(lmp, this);
    ready = true;
  }
  first_rows = RackStress::in_first(lmp, groupbit);
  RackStress::invalidate(lmp);
  post_force(vflag);
}

void FixRSAttract::post_force(int /*vflag*/)
{
  const int *tkey = tname.empty() ? nullptr : RackStress::ivector(atom, error, "rs/attract", tname);
  double **x = atom->x, **f = atom->f;
  int *mask = atom->mask;
  tagint *tag = atom->tag;
  int nlocal = RackStress::extent(atom, first_rows);    // the moving rows, where they hold all
  int maxkey = (int) by_key_first.size() - 2;
  RackStress::reduce_positions(lmp);    // fused with the step's other gathers
  const double *X = few.x.data();
  for (int i = 0; i < nlocal; i++) {
    if (!(mask[i] & groupbit)) continue;
    int v = tkey ? tkey[i] : 0;
    if (tkey && (v <= 0 || v > maxkey)) continue;    // Eq. 27: ⟨… ≠ 0⟩, or no member matches
    double a[3] = {0.0, 0.0, 0.0};
    for (int n = by_key_first[v]; n < by_key_first[v + 1]; n++) {
      int k = by_key[n];
      if (few.tag[k] == tag[i]) continue;    // a particle never attracts itself
      double d[3], d2 = 0.0;
      for (int e = 0; e < 3; e++) {
        d[e] = X[3 * k + e] - x[i][e];
        d2 += d[e] * d[e];
      }
      double s = c * (1.0 / std::sqrt(d2));
      for (int e = 0; e < 3; e++) a[e] += s * d[e];
    }
    if (!RackStress::finite3(a)) {    // coincides with a member (d = 0): rs_common.h
      RackStress::nonfinite(lmp, "rs/attract", tag[i]);
      continue;
    }
    double m = RackStress::mass(atom, i);
    for (int e = 0; e < 3; e++) f[i][e] += m * a[e];
  }
}
