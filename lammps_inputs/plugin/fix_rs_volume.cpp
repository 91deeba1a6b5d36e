/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/volume — a material part's volumetric term.

     fix ID GROUP rs/volume a c1 c2 c3 cmu btype T1 [T2 ...] [bind T C [T C ...]]

   The elastic lattice's bindings (Eq. 12 over the bonds of types T1 …, fix rs/bind) are
   central springs: alone they give every material Poisson's ratio 1/4. This adds to each
   particle i of GROUP the energy of its own cell's change of volume, quadratic terms in the
   extensions e_ij = ‖p_j − p_i‖ − L_ij of its own bonds (rackstress.model.volume, derived in
   docs/calibration.md "The volumetric term"):

     U_i/m = Σ_m ½·κ_m·θ_m²,   θ_m = Σ_j C_m,ij·e_ij

   * D_k = Σ_{j along axis k} e_ij/(n·L): its strain along each lattice axis (n = 2 inside,
     1 on a free face);
   * its cell, φ_k·a along axis k (per-atom d2_rsphi[1-3], 1 inside), split into the span toward
     its neighbours s_k = n_k/2 and the overhang h_k = φ_k − s_k: the sub-cell spanned along the
     axes S gets θ_S = Σ_{k∈S} D_k and κ = c_d·Π_S s·Π_rest h (c_d = λ'_d/ρ: bulk, plane
     stress, uniaxial stress, each less the bindings' own λ = μ), d the axes of S and those
     the particle is held along (d2_rsphi[4-6]: a support's overhang cannot contract; an axis
     along which it has no neighbour is not held: a sheet one particle thick stays in plane
     stress);
   * on a face particle (one free face, normal l, outward σ, its in-face neighbours and the
     four diagonals inward there): the overhang's in-plane strains at its centroid, Dc_k =
     (1 + h)·D_k − h·G_k, G_k = (e_{k−σl} + e_{−k−σl})/L_diag − e_{−σl}/L, with the membrane's
     moduli (λ₂ = c₂ + c_μ, 2μ) and what the face's bindings carry at the particle taken off
     (μ, 2μ): six terms in place of its in-plane sub-cell's.

   a is the lattice's spacing (a bond's lattice offset is (o_j − o_i)/a), c1 c2 c3 cmu the
   moduli per unit density (rackstress.model.volume.coefficients). Every θ_m is a sum of its
   particle's strains z = (D_0, D_1, D_2[, G_0, G_1]), so i's energy is ½·zᵀ·A_i·z with A_i =
   Σ_m κ_m·v_m·v_mᵀ (3 × 3, or 5 × 5 on a face particle), and each pair (i, j) is pulled with
   s = Σ (A·z)_k·∂z_k/∂e_ij over the strains that read it, i's and j's: f_i += m·s·d̂, f_j −=
   m·s·d̂ (the same forces as Σ_m κ_m·θ_m·C_m,ij, one pass over the pairs fewer). Every term
   reads its owner's own bonds only; the forces on partners this rank sees as ghosts are sent
   to their owners by one reverse communication a step.

   bind T C: the bonds of type T are also bound by this fix (Eq. 12, c·(u − p)·(1 − L0²/‖u −
   p‖²) with c = C, both ends in GROUP, as fix rs/bind GROUP GROUP C btype T): a pair the
   strains read in the pass that pulls it, the others in a pass of their own, so the
   nearest pairs are read once a step, not once for the bindings and again here. The deck
   then writes no rs/bind for those types.
------------------------------------------------------------------------- */

#include "fix_rs_volume.h"

#include "atom.h"
#include "comm.h"
#include "domain.h"
#include "error.h"
#include "force.h"
#include "neighbor.h"
#include "utils.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <unordered_map>

using namespace LAMMPS_NS;
using namespace FixConst;

FixRSVolume::FixRSVolume(LAMMPS *lmp, int narg, char **arg) :
    Fix(lmp, narg, arg), built(false)
{
  if (narg < 11 || strcmp(arg[8], "btype") != 0)
    error->all(FLERR, "Illegal fix rs/volume command: fix ID GROUP rs/volume a c1 c2 c3 cmu "
               "btype T1 [T2 ...] [bind T C [T C ...]]");
  a = utils::numeric(FLERR, arg[3], false, lmp);
  if (!(a > 0.0 && std::isfinite(a)))
    error->all(FLERR, "Fix rs/volume: spacing a must be positive, got {}", arg[3]);
  for (int k = 0; k < 3; k++) c[k] = utils::numeric(FLERR, arg[4 + k], false, lmp);
  cmu = utils::numeric(FLERR, arg[7], false, lmp);
  if (!(std::isfinite(c[0]) && std::isfinite(c[1]) && std::isfinite(c[2]) && std::isfinite(cmu)))
    error->all(FLERR, "Fix rs/volume: the moduli c1 c2 c3 cmu must be finite");
  int k = 9;
  for (; k < narg && strcmp(arg[k], "bind") != 0; k++) {
    int t = utils::inumeric(FLERR, arg[k], false, lmp);
    if (t < 1 || t > atom->nbondtypes)
      error->all(FLERR, "Fix rs/volume: btype {} is not a bond type (1..{})", t, atom->nbondtypes);
    btypes.push_back(t);
  }
  if (btypes.empty()) error->all(FLERR, "Fix rs/volume: btype needs at least one bond type");
  if (k < narg) {
    // bind T C …: the bonds of type T are this fix's to bind (Eq. 12, c = C), no rs/bind's
    if ((narg - k - 1) % 2 != 0 || narg - k - 1 == 0)
      error->all(FLERR, "Illegal fix rs/volume command: bind needs pairs of a bond type and its "
                 "c: bind T C [T C ...]");
    for (k++; k < narg; k += 2) {
      int t = utils::inumeric(FLERR, arg[k], false, lmp);
      double cb = utils::numeric(FLERR, arg[k + 1], false, lmp);
      if (std::find(btypes.begin(), btypes.end(), t) == btypes.end())
        error->all(FLERR, "Fix rs/volume: bind type {} is not one of its btype list", t);
      if (!(std::isfinite(cb) && cb != 0.0))
        error->all(FLERR, "Fix rs/volume: bind type {}'s c must be finite and not 0, got {}", t,
                   arg[k + 1]);
      bindtypes.push_back(t);
      bindc.push_back(cb);
    }
  }
  comm_reverse = 3;
}

int FixRSVolume::setmask()
{
  return POST_FORCE;
}

static double *cells(Atom *atom, Error *error)
{
  int flag, cols;
  int idx = atom->find_custom("rsphi", flag, cols);
  if (idx < 0 || flag != 1 || cols != 6)
    error->all(FLERR, "Fix rs/volume: needs each particle's cell extents and held directions as "
               "per-atom d2_rsphi 6 (fix property/atom d2_rsphi 6: φ 1 inside the part, held 0 "
               "or 1, set from volume.atoms)");
  return atom->darray[idx][0];
}

void FixRSVolume::init()
{
  RackStress::originals(atom, error, "rs/volume");
  cells(atom, error);
  if (force->newton_bond)
    error->all(FLERR, "Fix rs/volume needs newton_bond off ('newton on off' before read_data): "
               "each rank must list every bond of the atoms it owns");
}

void FixRSVolume::setup(int vflag)
{
  built = false;
  post_force(vflag);
}

/* the owned atoms' strains, their quadratic forms and the pairs (the file's doc), in atom-id
   order and each atom's bonds in its own order; a bond's lattice offset g = round((o_j − o_i)/a)
   indexes its direction. A pair two owned atoms both read (their shared nearest bond) is
   listed once, its extension feeding both atoms' strains. */
void FixRSVolume::collect()
{
  double **o = RackStress::originals(atom, error, "rs/volume");
  double *phi = cells(atom, error);
  int *mask = atom->mask;
  int nlocal = atom->nlocal;
  int *num_bond = atom->num_bond;
  int **bond_type = atom->bond_type;
  tagint **bond_atom = atom->bond_atom;
  auto ours = [&](int t) { return std::find(btypes.begin(), btypes.end(), t) != btypes.end(); };
  auto bound = [&](int t) {
    for (size_t k = 0; k < bindtypes.size(); k++)
      if (bindtypes[k] == t) return bindc[k];
    return 0.0;
  };
  rows.clear();
  for (int i = 0; i < nlocal; i++)
    if ((mask[i] & groupbit) && num_bond[i]) rows.push_back(i);
  RackStress::in_id_order(atom, nlocal, rows,
                          [&](int i) { return (mask[i] & groupbit) && num_bond[i]; });
  // every owned atom's bonds as pairs (before merging): rows, rest length, its binding's c
  std::vector<int> ri, rj;
  std::vector<double> rl, rq, rc;
  // (pair before merging, strain, weight)
  struct Entry {
    int p, slot;
    double w;
  };
  std::vector<Entry> ent;
  mptr.assign(1, 0);
  aptr.assign(1, 0);
  amat.clear();
  for (int i : rows) {
    // this atom's pairs by direction (27 offsets, 13 = none)
    int slot[27];
    std::fill(slot, slot + 27, -1);
    double count[3] = {0.0, 0.0, 0.0};
    int axis_of[27];
    for (int m = 0; m < num_bond[i]; m++) {
      if (!ours(bond_type[i][m])) continue;
      int j = atom->map(bond_atom[i][m]);
      if (j < 0) continue;    // not present: LAMMPS' own bond list stops the run ("missing")
      j = domain->closest_image(i, j);
      const double cb = bound(bond_type[i][m]);
      if (!(mask[j] & groupbit)) {
        if (cb != 0.0)
          error->one(FLERR, "Fix rs/volume: atoms {} and {} are bonded with type {}, which this "
                     "fix binds, but {} is not in its group",
                     (bigint) atom->tag[i], (bigint) atom->tag[j], bond_type[i][m],
                     (bigint) atom->tag[j]);
        continue;
      }
      int g[3], nz = 0, ax = 0;
      double l2 = 0.0;
      for (int k = 0; k < 3; k++) {
        double dl = o[j][k] - o[i][k];
        l2 += dl * dl;
        g[k] = (int) std::lround(dl / a);
        if (g[k] != 0) {
          nz++;
          ax = k;
        }
      }
      if (g[0] < -1 || g[0] > 1 || g[1] < -1 || g[1] > 1 || g[2] < -1 || g[2] > 1 || !nz)
        error->one(FLERR, "Fix rs/volume: atoms {} and {} are bonded {} spacings apart: the "
                   "term is for the cubic lattice's nearest and second neighbours",
                   (bigint) atom->tag[i], (bigint) atom->tag[j], std::sqrt(l2) / a);
      int dir = (g[0] + 1) * 9 + (g[1] + 1) * 3 + (g[2] + 1);
      slot[dir] = (int) ri.size();
      axis_of[dir] = nz == 1 ? ax : -1;
      if (nz == 1) count[ax] += 1.0;
      ri.push_back(i);
      rj.push_back(j);
      // (the same arithmetic as the Python's L = √(Σ (o_j − o_i)²))
      rl.push_back(std::sqrt(l2));
      rq.push_back(l2);
      rc.push_back(cb);
    }
    auto at = [&](int gx, int gy, int gz) { return slot[(gx + 1) * 9 + (gy + 1) * 3 + gz + 1]; };
    double s[3], h[3];
    bool held[3];
    for (int k = 0; k < 3; k++) {
      s[k] = 0.5 * count[k];
      h[k] = std::max(phi[6 * i + k] - s[k], 0.0);
      // a support across an axis along which the particle has no neighbour at all (a sheet
      // or a strut one particle thick held in its normal) holds no face: its overhangs stay
      // free to contract there (rackstress.model.volume.build, the same rule)
      held[k] = phi[6 * i + 3 + k] > 0.5 && count[k] > 0.0;
    }
    // a face particle: one axis with one neighbour, both along the other two, and the four
    // diagonals inward from the free face
    int ones = 0, twos = 0, l = -1, sg = 0;
    for (int k = 0; k < 3; k++) {
      if (count[k] == 1.0) {
        ones++;
        l = k;
      }
      if (count[k] == 2.0) twos++;
    }
    bool moment = false;
    int ks[2] = {0, 0};
    int dg[2][4], ax = -1;
    if (ones == 1 && twos == 2 && h[l] > 1e-12) {
      int e[3] = {0, 0, 0};
      e[l] = 1;
      sg = at(e[0], e[1], e[2]) < 0 ? 1 : -1;    // outward: no neighbour there
      int el[3] = {sg * e[0], sg * e[1], sg * e[2]};
      ax = at(-el[0], -el[1], -el[2]);
      moment = ax >= 0;
      int n = 0;
      for (int k = 0; k < 3 && moment; k++) {
        if (k == l) continue;
        ks[n] = k;
        int ek[3] = {0, 0, 0};
        ek[k] = 1;
        dg[n][0] = at(ek[0], ek[1], ek[2]);
        dg[n][1] = at(-ek[0], -ek[1], -ek[2]);
        dg[n][2] = at(ek[0] - el[0], ek[1] - el[1], ek[2] - el[2]);
        dg[n][3] = at(-ek[0] - el[0], -ek[1] - el[1], -ek[2] - el[2]);
        for (int q = 0; q < 4; q++) moment = moment && dg[n][q] >= 0;
        n++;
      }
    }
    // its strains z: D_0, D_1, D_2 (the strain along each axis) and, on a face particle,
    // G_0, G_1 (the gap's in-plane strains, without the h: Dc_n = (1 + h)·D_n − h·G_n)
    const int base = mptr.back(), nm = moment ? 5 : 3;
    for (int dir = 0; dir < 27; dir++)
      if (slot[dir] >= 0 && axis_of[dir] >= 0)
        ent.push_back({slot[dir], base + axis_of[dir],
                       1.0 / (count[axis_of[dir]] * rl[slot[dir]])});
    if (moment)
      for (int n = 0; n < 2; n++) {
        ent.push_back({dg[n][2], base + 3 + n, 1.0 / rl[dg[n][2]]});
        ent.push_back({dg[n][3], base + 3 + n, 1.0 / rl[dg[n][3]]});
        ent.push_back({ax, base + 3 + n, -1.0 / rl[ax]});
      }
    mptr.push_back(base + nm);
    // its quadratic form: U/m = ½·zᵀ·A·z, A = Σ_terms κ·v·vᵀ
    const size_t a0 = amat.size();
    amat.resize(a0 + nm * nm, 0.0);
    double *A = &amat[a0];
    auto add = [&](const double *v, double kap) {
      for (int u = 0; u < nm; u++)
        for (int w = 0; w < nm; w++) A[u * nm + w] += kap * v[u] * v[w];
    };
    // the sub-cells: θ_S = Σ_{k∈S} D_k
    for (int S = 1; S < 8; S++) {
      // the modulus of the axes free to contract: an overhang held across counts as spanned
      int d = 0;
      for (int k = 0; k < 3; k++) d += ((S >> k) & 1) || held[k] ? 1 : 0;
      double w = c[d - 1];
      for (int k = 0; k < 3; k++) w *= (S >> k) & 1 ? s[k] : h[k];
      if (moment && ((S >> 0) & 1) + ((S >> 1) & 1) + ((S >> 2) & 1) == 2 && !((S >> l) & 1))
        w = 0.0;    // at its centroid, below
      if (w == 0.0) continue;
      double v[5] = {0.0, 0.0, 0.0, 0.0, 0.0};
      for (int k = 0; k < 3; k++)
        if (((S >> k) & 1) && count[k] > 0.0) v[k] = 1.0;
      add(v, w);
    }
    aptr.push_back((int) amat.size());
    if (!moment) continue;
    // the overhang at its centroid: Q·Dc − C_b·D (six terms)
    const double hh = h[l], V = s[ks[0]] * s[ks[1]] * hh;
    auto term = [&](bool first, bool second, bool centroid, double kap) {
      double v[5] = {0.0, 0.0, 0.0, 0.0, 0.0};
      const bool use[2] = {first, second};
      for (int n = 0; n < 2; n++) {
        if (!use[n]) continue;
        v[ks[n]] = centroid ? 1.0 + hh : 1.0;
        if (centroid) v[3 + n] = -hh;
      }
      add(v, kap);
    };
    term(true, true, true, V * ((held[l] ? c[2] : c[1]) + cmu));
    term(true, false, true, 2.0 * V * cmu);
    term(false, true, true, 2.0 * V * cmu);
    term(true, true, false, -V * cmu);
    term(true, false, false, -2.0 * V * cmu);
    term(false, true, false, -2.0 * V * cmu);
  }
  // the pairs a strain reads, then those this fix only binds, each once
  std::vector<int> keep(ri.size(), -1);
  std::vector<char> read(ri.size(), 0);
  for (const Entry &q : ent) read[q.p] = 1;
  std::unordered_map<long long, int> seen;
  const long long nall = atom->nlocal + atom->nghost;
  pi.clear();
  pj.clear();
  pL.clear();
  pQ.clear();
  pc.clear();
  for (int sweep = 1; sweep >= 0; sweep--) {
    for (size_t p = 0; p < ri.size(); p++) {
      if (read[p] != sweep || (!sweep && rc[p] == 0.0)) continue;
      const long long lo = std::min(ri[p], rj[p]), hi = std::max(ri[p], rj[p]);
      auto it = seen.find(lo * nall + hi);
      if (it != seen.end()) {
        keep[p] = it->second;    // the same two rows: e and its direction are the pair's
        if (rc[p] != pc[it->second])
          error->one(FLERR, "Fix rs/volume: atoms {} and {} are bonded twice with different "
                     "types", (bigint) atom->tag[ri[p]], (bigint) atom->tag[rj[p]]);
        continue;
      }
      keep[p] = (int) pi.size();
      seen.emplace(lo * nall + hi, keep[p]);
      pi.push_back(ri[p]);
      pj.push_back(rj[p]);
      pL.push_back(rl[p]);
      pQ.push_back(rq[p]);
      pc.push_back(rc[p]);
    }
    if (sweep) nread = (int) pi.size();
  }
  // each pair's strains (CSR), in the order the atoms listed them
  const int np = (int) pi.size();
  qptr.assign(np + 1, 0);
  for (const Entry &q : ent) qptr[keep[q.p] + 1]++;
  for (int p = 0; p < np; p++) qptr[p + 1] += qptr[p];
  qslot.assign(ent.size(), 0);
  qw.assign(ent.size(), 0.0);
  std::vector<int> fill(qptr.begin(), qptr.end() - 1);
  for (const Entry &q : ent) {
    const int k = fill[keep[q.p]]++;
    qslot[k] = q.slot;
    qw[k] = q.w;
  }
  dist.assign(nread, 0.0);
  dvec.assign(3 * (size_t) nread, 0.0);
  z.assign(mptr.back(), 0.0);
  y.assign(mptr.back(), 0.0);
  built = true;
}

void FixRSVolume::post_force(int /*vflag*/)
{
  if (!built || neighbor->ago == 0) collect();
  const double *__restrict x = atom->x[0];
  const int np = (int) pi.size();
  const int *__restrict PI = pi.data(), *__restrict PJ = pj.data();
  const int *__restrict QP = qptr.data(), *__restrict QS = qslot.data();
  const double *__restrict QW = qw.data(), *__restrict L = pL.data();
  double *__restrict R = dist.data(), *__restrict Z = z.data(), *__restrict Y = y.data();
  double *__restrict DD = dvec.data();
  // each pair's extension into the strains that read it (its vector kept for the pull)
  std::fill(z.begin(), z.end(), 0.0);
  for (int p = 0; p < nread; p++) {
    const double *xi = x + 3 * PI[p], *xj = x + 3 * PJ[p];
    const double d0 = xj[0] - xi[0], d1 = xj[1] - xi[1], d2 = xj[2] - xi[2];
    const double r = std::sqrt(d0 * d0 + d1 * d1 + d2 * d2);
    R[p] = r;
    DD[3 * p] = d0;
    DD[3 * p + 1] = d1;
    DD[3 * p + 2] = d2;
    const double e = r - L[p];
    for (int q = QP[p]; q < QP[p + 1]; q++) Z[QS[q]] += QW[q] * e;
  }
  // each particle's quadratic form: y = A·z, ∂(U/m)/∂z
  const int nr = (int) rows.size();
  const int *__restrict MP = mptr.data(), *__restrict AP = aptr.data();
  const double *__restrict A = amat.data();
  for (int k = 0; k < nr; k++) {
    const int b = MP[k], m = MP[k + 1] - b;
    const double *a = A + AP[k];
    if (m == 3) {    // inside the part and on its edges
      const double z0 = Z[b], z1 = Z[b + 1], z2 = Z[b + 2];
      Y[b] = a[0] * z0 + a[1] * z1 + a[2] * z2;
      Y[b + 1] = a[3] * z0 + a[4] * z1 + a[5] * z2;
      Y[b + 2] = a[6] * z0 + a[7] * z1 + a[8] * z2;
      continue;
    }
    for (int u = 0; u < m; u++) {
      double t = 0.0;
      for (int v = 0; v < m; v++) t += a[u * m + v] * Z[b + v];
      Y[b + u] = t;
    }
  }
  // each pair pulled with s = Σ w·y over the strains that read it, and bound (Eq. 12) if
  // its type is one this fix binds: its owned ends only, the other's owner binds a ghost's.
  // f = m·a on the owned ends; a ghost's share waits in fv for its owner (reverse_comm)
  const int nlocal = atom->nlocal, nall = nlocal + atom->nghost;
  fv.resize(3 * (size_t) nall);
  std::fill(fv.begin() + 3 * (size_t) nlocal, fv.end(), 0.0);
  double *__restrict F = fv.data();
  double *__restrict f = atom->f[0];
  // unit masses (every generated deck's): f = a, the same bits as 1·a
  const bool unit = RackStress::unit_masses(atom);
  const double *__restrict C = pc.data(), *__restrict Q = pQ.data();
  auto add = [&](int i, int j, double gi, double g, double d0, double d1, double d2) {
    const double a0 = gi * d0, a1 = gi * d1, a2 = gi * d2;
    if (!std::isfinite(a0 + a1 + a2)) {    // (inf − inf is NaN: one test for the three)
      // a pair that coincides (d = 0): neither end gains it (rs_common.h, nonfinite)
      RackStress::nonfinite(lmp, "rs/volume", std::min(atom->tag[i], atom->tag[j]));
      return;
    }
    const double mi = unit ? 1.0 : RackStress::mass(atom, i);
    f[3 * i] += mi * a0;
    f[3 * i + 1] += mi * a1;
    f[3 * i + 2] += mi * a2;
    if (j < nlocal) {
      const double mj = unit ? 1.0 : RackStress::mass(atom, j);
      f[3 * j] -= mj * a0;
      f[3 * j + 1] -= mj * a1;
      f[3 * j + 2] -= mj * a2;
    } else {
      F[3 * j] -= g * d0;
      F[3 * j + 1] -= g * d1;
      F[3 * j + 2] -= g * d2;
    }
  };
  for (int p = 0; p < nread; p++) {
    double s = 0.0;
    for (int q = QP[p]; q < QP[p + 1]; q++) s += QW[q] * Y[QS[q]];
    const int i = PI[p], j = PJ[p];
    const double d0 = DD[3 * p], d1 = DD[3 * p + 1], d2 = DD[3 * p + 2];
    const double g = s / R[p];
    const double gb =
        C[p] == 0.0 ? 0.0 : RackStress::eq12(C[p], Q[p], d0 * d0 + d1 * d1 + d2 * d2);
    add(i, j, g + gb, g, d0, d1, d2);
  }
  // the pairs it only binds (Eq. 12, fix rs/bind's arithmetic)
  for (int p = nread; p < np; p++) {
    const int i = PI[p], j = PJ[p];
    const double *xi = x + 3 * i, *xj = x + 3 * j;
    const double d0 = xj[0] - xi[0], d1 = xj[1] - xi[1], d2 = xj[2] - xi[2];
    add(i, j, RackStress::eq12(C[p], Q[p], d0 * d0 + d1 * d1 + d2 * d2), 0.0, d0, d1, d2);
  }
  // the partners' shares this rank computed as ghosts go to their owners
  if (comm->nprocs > 1) comm->reverse_comm(this);
}

int FixRSVolume::pack_reverse_comm(int n, int first, double *buf)
{
  int m = 0;
  for (int i = first; i < first + n; i++) {
    buf[m++] = fv[3 * i];
    buf[m++] = fv[3 * i + 1];
    buf[m++] = fv[3 * i + 2];
  }
  return m;
}

/* a ghost's share, added to its owner's force (f = m·a) */
void FixRSVolume::unpack_reverse_comm(int n, int *list, double *buf)
{
  double **f = atom->f;
  for (int i = 0; i < n; i++) {
    const int j = list[i];
    const double *a3 = buf + 3 * i;
    if (!RackStress::finite3(a3)) {
      RackStress::nonfinite(lmp, "rs/volume", atom->tag[j]);
      continue;
    }
    const double m = RackStress::mass(atom, j);
    f[j][0] += m * a3[0];
    f[j][1] += m * a3[1];
    f[j][2] += m * a3[2];
  }
}
