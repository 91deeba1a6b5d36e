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
   the host rows, four rack members at a time in vector lanes (gcc/clang vector extension),
   compiled twice: for AVX2 where the processor has it, else for the baseline. Every sum is added
   in the scalar loop's order (a member's over the rows in id order, a row's over the members in
   id order) and nothing is contracted into a fused multiply-add, so either build gives the same
   bits as the plain loop. */
namespace {
typedef double v4d __attribute__((vector_size(32)));

struct FusedPass {
  double **x;
  const int *rows;
  size_t nrows;
  const double *l0sq;        // [row][n4], zero past n
  int n, n4;
  const double *members;     // x, y, z of each member, n4 each, zero past n
  double c, cr;              // this coupling's c (rack <- host), the reverse's (host <- rack)
  double *acc;               // out: the host rows' accelerations, 3 per row
  double *sums;              // out: the members' sums over the rows, [x|y|z][n4]
};

typedef double v2d __attribute__((vector_size(16)));

inline v2d load2(const double *p)
{
  v2d v;
  std::memcpy(&v, p, sizeof(v2d));
  return v;
}

/* one block of W members (W = 4 or 2) of row p: its terms into the block's sums S[0..2], and,
   member by member (m of them are real), into the row's acceleration a */
template <class V, int W>
inline __attribute__((always_inline)) void fused_block(const V &px, const V &py, const V &pz,
                                                       const double *mx, const double *my,
                                                       const double *mz, const double *q,
                                                       const V &c, const V &cr, V *S, int m,
                                                       double *a)
{
  V ux, uy, uz, l0;
  std::memcpy(&ux, mx, sizeof(V));
  std::memcpy(&uy, my, sizeof(V));
  std::memcpy(&uz, mz, sizeof(V));
  std::memcpy(&l0, q, sizeof(V));
  const V dx = px - ux, dy = py - uy, dz = pz - uz;
  const V d2 = dx * dx + dy * dy + dz * dz;
  const V t = 1.0 - l0 / d2;
  const V s = c * t, sr = cr * t;
  S[0] += s * dx;
  S[1] += s * dy;
  S[2] += s * dz;
  const V tx = sr * -dx, ty = sr * -dy, tz = sr * -dz;
  for (int l = 0; l < (m < W ? m : W); l++) {
    a[0] += tx[l];
    a[1] += ty[l];
    a[2] += tz[l];
  }
}

/* NB blocks of four members (NB = 0: as many as the rack needs, nb), then, with TAIL = 2, one
   block of two (a rack of 4·NB + 1 or 4·NB + 2 members: half the divisions of a padded four) */
template <int NB, int TAIL>
inline __attribute__((always_inline)) void fused_blocks(const FusedPass &P, int nb)
{
  const int n = P.n, n4 = P.n4;
  const int B = NB > 0 ? NB : nb;
  const double *MX = P.members, *MY = MX + n4, *MZ = MY + n4;
  v4d Sfix[3 * (NB > 0 ? NB : 1)];
  std::vector<v4d> Sdyn(NB > 0 ? 0 : 3 * nb);
  v4d *S = NB > 0 ? Sfix : Sdyn.data();
  for (int k = 0; k < 3 * B; k++) S[k] = v4d{0.0, 0.0, 0.0, 0.0};
  v2d St[3] = {{0.0, 0.0}, {0.0, 0.0}, {0.0, 0.0}};
  const v4d c = {P.c, P.c, P.c, P.c}, cr = {P.cr, P.cr, P.cr, P.cr};
  const v2d c2 = {P.c, P.c}, cr2 = {P.cr, P.cr};
  for (size_t r = 0; r < P.nrows; r++) {
    const double *p = P.x[P.rows[r]];
    const v4d px = {p[0], p[0], p[0], p[0]}, py = {p[1], p[1], p[1], p[1]},
              pz = {p[2], p[2], p[2], p[2]};
    double a[3] = {0.0, 0.0, 0.0};
    const double *q = P.l0sq + r * n4;
    for (int b = 0; b < B; b++)
      fused_block<v4d, 4>(px, py, pz, MX + 4 * b, MY + 4 * b, MZ + 4 * b, q + 4 * b, c, cr,
                          S + 3 * b, n - 4 * b, a);
    if (TAIL == 2) {
      const v2d qx = {p[0], p[0]}, qy = {p[1], p[1]}, qz = {p[2], p[2]};
      fused_block<v2d, 2>(qx, qy, qz, MX + 4 * B, MY + 4 * B, MZ + 4 * B, q + 4 * B, c2, cr2,
                          St, n - 4 * B, a);
    }
    P.acc[3 * r] = a[0];
    P.acc[3 * r + 1] = a[1];
    P.acc[3 * r + 2] = a[2];
  }
  for (int b = 0; b < B; b++)
    for (int e = 0; e < 3; e++) std::memcpy(P.sums + e * n4 + 4 * b, &S[3 * b + e], sizeof(v4d));
  if (TAIL == 2)
    for (int e = 0; e < 3; e++) std::memcpy(P.sums + e * n4 + 4 * B, &St[e], sizeof(v2d));
}

inline __attribute__((always_inline)) void fused_any(const FusedPass &P)
{
  const int nb = P.n4 / 4, rest = P.n % 4;
  if (nb == 1 && rest == 0) fused_blocks<1, 0>(P, nb);
  else if (nb == 1 && rest <= 2) fused_blocks<0, 2>(P, 0);
  else if (nb == 2 && rest == 0) fused_blocks<2, 0>(P, nb);
  else if (nb == 2 && rest <= 2) fused_blocks<1, 2>(P, 1);    // the six-particle racks of the scenes
  else fused_blocks<0, 0>(P, nb);
}

__attribute__((target("avx2"))) void fused_avx2(const FusedPass &P)
{
  fused_any(P);
}

void fused_base(const FusedPass &P)
{
  fused_any(P);
}

void fused_pass(const FusedPass &P)
{
  static const bool avx2 = __builtin_cpu_supports("avx2");
  if (avx2) fused_avx2(P);
  else fused_base(P);
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
    // the same, four members to a vector lane block (the fused pass, partial)
    const int n4 = (n + 3) / 4 * 4;
    l0sq4.assign(rows.size() * n4, 0.0);
    for (size_t r = 0; r < rows.size(); r++)
      std::copy(l0sq.begin() + r * n, l0sq.begin() + (r + 1) * n, l0sq4.begin() + r * n4);
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
    // Four rack members at a time in vector lanes (gcc/clang vector extension); every sum is
    // still added in the scalar loop's order (a member's over the rows in id order, a row's
    // over the members in id order), so the result is the same to the bit.
    const int n = few.size(), n4 = (n + 3) / 4 * 4;
    const std::vector<int> &R = reverse->owned_rows();
    // the members' positions, a coordinate at a time, zero past n (a padded lane's terms are
    // finite, d = p, and never added: its sum is not read, a row's sum stops at n)
    lanes.assign(3 * n4, 0.0);
    for (int k = 0; k < n; k++)
      for (int e = 0; e < 3; e++) lanes[e * n4 + k] = few.x[3 * k + e];
    lanesum.assign(3 * n4, 0.0);
    reverse->acc.resize(3 * R.size());
    FusedPass P{atom->x, R.data(), R.size(), reverse->l0sq4.data(), n, n4, lanes.data(),
                c, reverse->c, reverse->acc.data(), lanesum.data()};
    fused_pass(P);
    for (int k = 0; k < n; k++)
      for (int e = 0; e < 3; e++) sum[3 * k + e] += lanesum[e * n4 + k];
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
      double s = c * (1.0 - Q[r * n + k] / d2);
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
        double s = c * (1.0 - Q[r * n + k] / d2);
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
