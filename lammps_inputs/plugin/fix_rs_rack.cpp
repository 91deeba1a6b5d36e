/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/rack — the rack coupling of Eq. 23.

     fix ID TARGET rs/rack SOURCE c

   rackForces(host) (Eq. 23) binds a rack to its host with bind over every pair (Eq. 13 with
   ĉ = [c]), and the host to its rack the same way. On each target particle p, from every source
   particle u (never p itself), the acceleration of Eq. 12:

     c·(u − p)·(1 − L0²/‖u − p‖²),   L0 = ‖u_o − p_o‖ (original positions)

   Every pair couples a whole body, so ghosts cannot carry it. As fix rigid sums its bodies, the
   smaller group (the six rack particles) is gathered on every rank with an MPI_Allreduce a step;
   a host particle's term is then local, and a rack particle's sum over its host is each rank's
   partial sum over the hosts it owns, added up by one more MPI_Allreduce. Both are fused with
   every other style's reductions of the step (rs_common.h, Reduced): two collectives a step.
------------------------------------------------------------------------- */

#include "fix_rs_rack.h"

#include "atom.h"
#include "error.h"
#include "group.h"
#include "modify.h"
#include "neighbor.h"
#include "update.h"
#include "utils.h"

#include <algorithm>
#include <cmath>
#include <cstring>

using namespace LAMMPS_NS;
using namespace FixConst;

/* The fused pass of FixRSRack::partial (both directions of a rack coupling, Eq. 12 each) over
   the host rows, four host rows at a time in vector lanes (gcc/clang vector extension),
   compiled twice: for AVX2 where the processor has it, else for the baseline (the same bits
   either way: the same operations in the same order, none contracted into a fused
   multiply-add). A row's acceleration is summed over the members in id order, in its lane; a
   member's sum over the rows is four lane sums (rows r ≡ l mod 4 of the full blocks of four,
   the last rows in lane 0) added at the end: a fixed order, so a run and its resumed run stay
   bit for bit equal. l0sq is transposed for it ([member][row]). */
namespace {
typedef double v4d __attribute__((vector_size(32)));

struct RowsPass {
  double **x;
  const int *rows;
  size_t nrows;
  const double *l0t;         // [member][nrows]
  int n;
  const double *X;           // the members' positions, 3 per member
  double c, cr;
  double *acc;               // out: 3 per row
  double *sums;              // out: 3 per member
};

inline __attribute__((always_inline)) void rows_pass_any(const RowsPass &P)
{
  const int n = P.n;
  const size_t nr = P.nrows, full = nr / 4 * 4;
  // the lane sums as plain doubles (a heap vector of v4d need not be 32-byte aligned)
  std::vector<double> S(12 * n, 0.0);
  auto add4 = [&S](int at, const v4d &v) {
    v4d w;
    std::memcpy(&w, &S[4 * at], sizeof(v4d));
    w += v;
    std::memcpy(&S[4 * at], &w, sizeof(v4d));
  };
  const v4d c = {P.c, P.c, P.c, P.c}, cr = {P.cr, P.cr, P.cr, P.cr};
  for (size_t r = 0; r < full; r += 4) {
    const double *p0 = P.x[P.rows[r]], *p1 = P.x[P.rows[r + 1]], *p2 = P.x[P.rows[r + 2]],
                 *p3 = P.x[P.rows[r + 3]];
    const v4d px = {p0[0], p1[0], p2[0], p3[0]}, py = {p0[1], p1[1], p2[1], p3[1]},
              pz = {p0[2], p1[2], p2[2], p3[2]};
    v4d ax = {0.0, 0.0, 0.0, 0.0}, ay = ax, az = ax;
    for (int k = 0; k < n; k++) {
      const double *u = P.X + 3 * k;
      const v4d dx = px - u[0], dy = py - u[1], dz = pz - u[2];
      const v4d d2 = dx * dx + dy * dy + dz * dz;
      v4d q;
      std::memcpy(&q, P.l0t + k * nr + r, sizeof(v4d));
      const v4d t = 1.0 - q / d2;
      const v4d s = c * t, sr = cr * t;
      add4(3 * k, s * dx);
      add4(3 * k + 1, s * dy);
      add4(3 * k + 2, s * dz);
      ax += sr * -dx;
      ay += sr * -dy;
      az += sr * -dz;
    }
    for (int l = 0; l < 4; l++) {
      P.acc[3 * (r + l)] = ax[l];
      P.acc[3 * (r + l) + 1] = ay[l];
      P.acc[3 * (r + l) + 2] = az[l];
    }
  }
  double tail[3 * 64];
  std::vector<double> big;
  double *T = tail;
  if (3 * n > 3 * 64) {
    big.assign(3 * n, 0.0);
    T = big.data();
  } else
    std::fill(T, T + 3 * n, 0.0);
  for (size_t r = full; r < nr; r++) {
    const double *p = P.x[P.rows[r]];
    double a[3] = {0.0, 0.0, 0.0};
    for (int k = 0; k < n; k++) {
      const double *u = P.X + 3 * k;
      double d[3] = {p[0] - u[0], p[1] - u[1], p[2] - u[2]};
      double d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
      double t = 1.0 - P.l0t[k * nr + r] / d2;
      double s = P.c * t, sr = P.cr * t;
      for (int e = 0; e < 3; e++) {
        T[3 * k + e] += s * d[e];
        a[e] += sr * -d[e];
      }
    }
    for (int e = 0; e < 3; e++) P.acc[3 * r + e] = a[e];
  }
  for (int k = 0; k < n; k++)
    for (int e = 0; e < 3; e++) {
      const double *v = &S[4 * (3 * k + e)];
      P.sums[3 * k + e] = (((v[0] + T[3 * k + e]) + v[1]) + v[2]) + v[3];
    }
}

__attribute__((target("avx2"))) void rows_avx2(const RowsPass &P)
{
  rows_pass_any(P);
}

void rows_base(const RowsPass &P)
{
  rows_pass_any(P);
}

void rows_pass(const RowsPass &P)
{
  static const bool avx2 = __builtin_cpu_supports("avx2");
  if (avx2) rows_avx2(P);
  else rows_base(P);
}
}    // namespace

FixRSRack::FixRSRack(LAMMPS *lmp, int narg, char **arg) :
    Fix(lmp, narg, arg), gather_source(true), ready(false), rows_built(false), overlap(true)
{
  if (narg != 5) error->all(FLERR, "Illegal fix rs/rack command: fix ID TARGET rs/rack SOURCE c");
  sourcebit = RackStress::groupbit(group, error, "rs/rack", "source", arg[3]);
  c = utils::numeric(FLERR, arg[4], false, lmp);
  if (!std::isfinite(c)) error->all(FLERR, "Fix rs/rack: coefficient c must be finite, got {}", arg[4]);
}

FixRSRack::~FixRSRack()
{
  RackStress::leave(lmp, this);
}

int FixRSRack::setmask()
{
  return POST_FORCE;
}

void FixRSRack::init()
{
  RackStress::originals(atom, error, "rs/rack");
}

void FixRSRack::setup(int vflag)
{
  if (!ready) {
    // gather whichever side is smaller: the rack (host <- rack: the sources; rack <- host: the
    // targets, whose sums over the host are reduced)
    int sgroup = -1;
    for (int g = 0; g < group->ngroup; g++)
      if (group->bitmask[g] == sourcebit) sgroup = g;
    gather_source = group->count(sgroup) <= group->count(igroup);
    few.collect(lmp, gather_source ? sourcebit : groupbit, nullptr);
    sums.assign(3 * few.size(), 0.0);
    int both = 0, any = 0;
    for (int i = 0; i < atom->nlocal; i++)
      if ((atom->mask[i] & groupbit) && (atom->mask[i] & sourcebit)) both = 1;
    MPI_Allreduce(&both, &any, 1, MPI_INT, MPI_MAX, world);
    overlap = any != 0;
    RackStress::enroll(lmp, this);
    ready = true;
  }
  rows_built = false;
  reverse = nullptr;
  acc_step = -1;
  first_rows = RackStress::in_first(lmp, gather_source ? groupbit : sourcebit);
  RackStress::invalidate(lmp);
  post_force(vflag);
}

const std::vector<int> &FixRSRack::owned_rows()
{
  if (!rows_built || neighbor->ago == 0) {
    int bit = gather_source ? groupbit : sourcebit;
    rows.clear();
    const int nrows = RackStress::extent(atom, first_rows);    // the moving rows, where they hold all
    for (int i = 0; i < nrows; i++)
      if (atom->mask[i] & bit) rows.push_back(i);
    // in atom-id order: a rank's partial sum over its hosts depends only on which it owns
    int *mask = atom->mask;
    RackStress::in_id_order(atom, nrows, rows, [mask, bit](int i) { return (mask[i] & bit) != 0; });
    // L0² = ‖u_o − p_o‖² of every pair, once a layout (the same arithmetic as a step's would be)
    double **o = RackStress::originals(atom, error, "rs/rack");
    int n = few.size();
    const double *O = few.o.data();
    l0sq.assign(rows.size() * n, 0.0);
    own.assign(rows.size() * n, 0);
    for (size_t r = 0; r < rows.size(); r++) {
      int i = rows[r];
      for (int k = 0; k < n; k++) {
        double q = 0.0;
        for (int e = 0; e < 3; e++) {
          double l = gather_source ? O[3 * k + e] - o[i][e] : o[i][e] - O[3 * k + e];
          q += l * l;
        }
        l0sq[r * n + k] = q;
        own[r * n + k] = overlap && few.tag[k] == atom->tag[i];
      }
    }
    // transposed for the fused pass (rows_pass)
    l0t.assign(rows.size() * n, 0.0);
    for (size_t r = 0; r < rows.size(); r++)
      for (int k = 0; k < n; k++) l0t[k * rows.size() + r] = l0sq[r * n + k];
    rows_built = true;
  }
  return rows;
}

int FixRSRack::partial_size()
{
  return gather_source ? 0 : 3 * few.size();
}

/* the rs/rack fix of the reverse coupling (host <- rack, gathering its sources: this one's
   targets), when the two can share a pass: the same rack members and host rows, no atom in both */
FixRSRack *FixRSRack::find_reverse()
{
  if (gather_source || overlap) return nullptr;
  for (int m = 0; m < modify->nfix; m++) {
    auto *other = dynamic_cast<FixRSRack *>(modify->fix[m]);
    if (other && other != this && other->ready && other->gather_source && !other->overlap &&
        other->groupbit == sourcebit && other->sourcebit == groupbit && other->few.tag == few.tag)
      return other;
  }
  return nullptr;
}

/* the gathered targets (a rack) sum over every source u (the host): this rank's hosts */
void FixRSRack::partial(double *sum)
{
  if (gather_source) return;
  if (!reverse) reverse = find_reverse();
  if (reverse) {
    // one pass for both couplings over the reverse fix's host rows (the same rows, in the same
    // order, as this one's): t = 1 − L0²/‖u − p‖² once per pair, c·t·(p − u) summed into the
    // rack member's partial sum, c'·t·(u − p) into the host row's acceleration (Eq. 12 each).
    // Four host rows at a time in vector lanes (rows_pass above).
    const int n = few.size();
    const std::vector<int> &R = reverse->owned_rows();
    lanesum.assign(3 * n, 0.0);
    reverse->acc.resize(3 * R.size());
    RowsPass P{atom->x, R.data(), R.size(), reverse->l0t.data(), n, few.x.data(), c,
               reverse->c, reverse->acc.data(), lanesum.data()};
    rows_pass(P);
    for (int k = 0; k < 3 * n; k++) sum[k] += lanesum[k];
    reverse->acc_step = update->ntimestep;
    return;
  }
  double **x = atom->x;
  int n = few.size();
  const double *X = few.x.data();
  const std::vector<int> &R = owned_rows();
  const double *Q = l0sq.data();
  const char *skip = own.data();
  for (size_t r = 0; r < R.size(); r++) {
    const double *p = x[R[r]];
    for (int k = 0; k < n; k++) {
      if (skip[r * n + k]) continue;
      double d[3], d2 = 0.0;
      for (int e = 0; e < 3; e++) {
        d[e] = p[e] - X[3 * k + e];
        d2 += d[e] * d[e];
      }
      double s = RackStress::eq12(c, Q[r * n + k], d2);
      for (int e = 0; e < 3; e++) sum[3 * k + e] += s * d[e];
    }
  }
}

void FixRSRack::total(const double *sum)
{
  std::copy(sum, sum + sums.size(), sums.begin());
}

void FixRSRack::post_force(int /*vflag*/)
{
  double **x = atom->x, **f = atom->f;
  int nlocal = atom->nlocal, n = few.size();

  if (gather_source) {
    // a target p gains the term of every gathered source u (Eq. 12), in atom-id order
    RackStress::reduce_positions(lmp);
    RackStress::reduce_sums(lmp);    // a reverse coupling fused with this one fills acc there
    const std::vector<int> &R = owned_rows();
    if (acc_step == update->ntimestep && acc.size() == 3 * R.size()) {
      for (size_t r = 0; r < R.size(); r++) {
        int i = R[r];
        if (!RackStress::finite3(&acc[3 * r])) {    // coincides with a rack particle
          RackStress::nonfinite(lmp, "rs/rack", atom->tag[i]);
          continue;
        }
        double m = RackStress::mass(atom, i);
        for (int e = 0; e < 3; e++) f[i][e] += m * acc[3 * r + e];
      }
      return;
    }
    const double *X = few.x.data();
    const double *Q = l0sq.data();
    const char *skip = own.data();
    for (size_t r = 0; r < R.size(); r++) {
      int i = R[r];
      double a[3] = {0.0, 0.0, 0.0};
      for (int k = 0; k < n; k++) {
        if (skip[r * n + k]) continue;
        double d[3], d2 = 0.0;
        for (int e = 0; e < 3; e++) {
          d[e] = X[3 * k + e] - x[i][e];
          d2 += d[e] * d[e];
        }
        double s = RackStress::eq12(c, Q[r * n + k], d2);
        for (int e = 0; e < 3; e++) a[e] += s * d[e];
      }
      if (!RackStress::finite3(a)) {    // coincides with a rack particle: rs_common.h
        RackStress::nonfinite(lmp, "rs/rack", atom->tag[i]);
        continue;
      }
      double m = RackStress::mass(atom, i);
      for (int e = 0; e < 3; e++) f[i][e] += m * a[e];
    }
    return;
  }
  // each rank's partial sums over the hosts it owns, added over the ranks (fused with every
  // other style's, rs_common.h); the target's owner adds the force
  RackStress::reduce_sums(lmp);
  for (int k = 0; k < n; k++) {
    int i = atom->map(few.tag[k]);
    if (i < 0 || i >= nlocal) continue;
    if (!RackStress::finite3(&sums[3 * k])) {    // a host particle coincides with it
      RackStress::nonfinite(lmp, "rs/rack", few.tag[k]);
      continue;
    }
    double m = RackStress::mass(atom, i);
    for (int e = 0; e < 3; e++) f[i][e] += m * sums[3 * k + e];
  }
}
