/* ----------------------------------------------------------------------
   rackstress plugin: fix rs/volume — a material part's volumetric term.

     fix ID GROUP rs/volume a c1 c2 c3 cmu btype T1 [T2 ...]

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
     the particle is held along (d2_rsphi[4-6]: a support's overhang cannot contract);
   * on a face particle (one free face, normal l, outward σ, its in-face neighbours and the
     four diagonals inward there): the overhang's in-plane strains at its centroid, Dc_k =
     (1 + h)·D_k − h·G_k, G_k = (e_{k−σl} + e_{−k−σl})/L_diag − e_{−σl}/L, with the membrane's
     moduli (λ₂ = c₂ + c_μ, 2μ) and what the face's bindings carry at the particle taken off
     (μ, 2μ): six terms in place of its in-plane sub-cell's.

   a is the lattice's spacing (a bond's lattice offset is (o_j − o_i)/a), c1 c2 c3 cmu the
   moduli per unit density (rackstress.model.volume.coefficients). Each pair (i, j) of i's terms
   is pulled with s = Σ_m κ_m·θ_m·C_m,ij along it: f_i += m·s·d̂, f_j −= m·s·d̂. Every term
   reads its owner's own bonds only; the forces on partners this rank sees as ghosts are sent
   to their owners by one reverse communication a step.
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
               "btype T1 [T2 ...]");
  a = utils::numeric(FLERR, arg[3], false, lmp);
  if (!(a > 0.0 && std::isfinite(a)))
    error->all(FLERR, "Fix rs/volume: spacing a must be positive, got {}", arg[3]);
  for (int k = 0; k < 3; k++) c[k] = utils::numeric(FLERR, arg[4 + k], false, lmp);
  cmu = utils::numeric(FLERR, arg[7], false, lmp);
  if (!(std::isfinite(c[0]) && std::isfinite(c[1]) && std::isfinite(c[2]) && std::isfinite(cmu)))
    error->all(FLERR, "Fix rs/volume: the moduli c1 c2 c3 cmu must be finite");
  for (int k = 9; k < narg; k++) {
    int t = utils::inumeric(FLERR, arg[k], false, lmp);
    if (t < 1 || t > atom->nbondtypes)
      error->all(FLERR, "Fix rs/volume: btype {} is not a bond type (1..{})", t, atom->nbondtypes);
    btypes.push_back(t);
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

/* the owned atoms' pairs and terms (the file's doc), in atom-id order and each atom's bonds in
   its own order; a bond's lattice offset g = round((o_j − o_i)/a) indexes its direction */
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
  rows.clear();
  for (int i = 0; i < nlocal; i++)
    if ((mask[i] & groupbit) && num_bond[i]) rows.push_back(i);
  RackStress::in_id_order(atom, nlocal, rows,
                          [&](int i) { return (mask[i] & groupbit) && num_bond[i]; });
  pi.clear();
  pj.clear();
  pL.clear();
  tptr.assign(1, 0);
  tpair.clear();
  tval.clear();
  tkappa.clear();
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
      if (!(mask[j] & groupbit)) continue;
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
      slot[dir] = (int) pi.size();
      axis_of[dir] = nz == 1 ? ax : -1;
      if (nz == 1) count[ax] += 1.0;
      pi.push_back(i);
      pj.push_back(j);
      // (the same arithmetic as the Python's L = √(Σ (o_j − o_i)²))
      pL.push_back(std::sqrt(l2));
    }
    auto at = [&](int gx, int gy, int gz) { return slot[(gx + 1) * 9 + (gy + 1) * 3 + gz + 1]; };
    double s[3], h[3];
    bool held[3];
    for (int k = 0; k < 3; k++) {
      s[k] = 0.5 * count[k];
      h[k] = std::max(phi[6 * i + k] - s[k], 0.0);
      held[k] = phi[6 * i + 3 + k] > 0.5;
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
    // the sub-cells
    for (int S = 1; S < 8; S++) {
      // the modulus of the axes free to contract: an overhang held across counts as spanned
      int d = 0;
      for (int k = 0; k < 3; k++) d += ((S >> k) & 1) || held[k] ? 1 : 0;
      double w = c[d - 1];
      for (int k = 0; k < 3; k++) w *= (S >> k) & 1 ? s[k] : h[k];
      if (moment && ((S >> 0) & 1) + ((S >> 1) & 1) + ((S >> 2) & 1) == 2 && !((S >> l) & 1))
        w = 0.0;    // at its centroid, below
      if (w == 0.0) continue;
      for (int dir = 0; dir < 27; dir++) {
        int p = slot[dir];
        if (p < 0 || axis_of[dir] < 0 || !((S >> axis_of[dir]) & 1)) continue;
        tpair.push_back(p);
        tval.push_back(1.0 / (count[axis_of[dir]] * pL[p]));
      }
      tkappa.push_back(w);
      tptr.push_back((int) tpair.size());
    }
    if (!moment) continue;
    // the overhang at its centroid: Q·Dc − C_b·D (six terms)
    const double hh = h[l], V = s[ks[0]] * s[ks[1]] * hh;
    auto term = [&](const int *which, int nwhich, bool centroid, double kap) {
      // θ = Σ over the in-plane axes listed of D_k (or Dc_k); duplicates summed
      std::vector<std::pair<int, double>> ent;
      for (int q = 0; q < nwhich; q++) {
        int n = which[q];
        int pp = dg[n][0], pm = dg[n][1];
        double b = 1.0 / (count[ks[n]] * pL[pp]), bm = 1.0 / (count[ks[n]] * pL[pm]);
        double f = centroid ? 1.0 + hh : 1.0;
        ent.emplace_back(pp, f * b);
        ent.emplace_back(pm, f * bm);
        if (centroid) {
          ent.emplace_back(dg[n][2], -hh / pL[dg[n][2]]);
          ent.emplace_back(dg[n][3], -hh / pL[dg[n][3]]);
          ent.emplace_back(ax, hh / pL[ax]);
        }
      }
      std::sort(ent.begin(), ent.end(),
                [](const std::pair<int, double> &x, const std::pair<int, double> &y) {
                  return x.first < y.first;
                });
      for (size_t q = 0; q < ent.size(); q++) {
        if (q && ent[q].first == ent[q - 1].first) {
          tval.back() += ent[q].second;
          continue;
        }
        tpair.push_back(ent[q].first);
        tval.push_back(ent[q].second);
      }
      tkappa.push_back(kap);
      tptr.push_back((int) tpair.size());
    };
    const int both[2] = {0, 1}, first[1] = {0}, second[1] = {1};
    term(both, 2, true, V * ((held[l] ? c[2] : c[1]) + cmu));
    term(first, 1, true, 2.0 * V * cmu);
    term(second, 1, true, 2.0 * V * cmu);
    term(both, 2, false, -V * cmu);
    term(first, 1, false, -2.0 * V * cmu);
    term(second, 1, false, -2.0 * V * cmu);
  }
  // only the pairs some term reads (inside the part the six nearest), each once: a pair two
  // owned atoms both read (their shared nearest bond) is measured and pulled once, by both
  // terms' sums — the step passes over those alone
  std::vector<int> keep(pi.size(), -1);
  for (int p : tpair) keep[p] = 0;
  std::unordered_map<long long, int> seen;
  const long long nall = atom->nlocal + atom->nghost;
  int nkeep = 0;
  for (size_t p = 0; p < pi.size(); p++) {
    if (keep[p] != 0) continue;
    const long long lo = std::min(pi[p], pj[p]), hi = std::max(pi[p], pj[p]);
    auto it = seen.find(lo * nall + hi);
    if (it != seen.end()) {
      keep[p] = it->second;    // the same two rows: e and its direction are the pair's
      continue;
    }
    seen.emplace(lo * nall + hi, nkeep);
    keep[p] = nkeep;
    pi[nkeep] = pi[p];
    pj[nkeep] = pj[p];
    pL[nkeep] = pL[p];
    nkeep++;
  }
  pi.resize(nkeep);
  pj.resize(nkeep);
  pL.resize(nkeep);
  for (int &p : tpair) p = keep[p];
  e.assign(pi.size(), 0.0);
  pull.assign(pi.size(), 0.0);
  built = true;
}

void FixRSVolume::post_force(int /*vflag*/)
{
  if (!built || neighbor->ago == 0) collect();
  const double *__restrict x = atom->x[0];
  const int np = (int) pi.size();
  const int *__restrict PI = pi.data(), *__restrict PJ = pj.data();
  const double *__restrict L = pL.data();
  double *__restrict E = e.data(), *__restrict P = pull.data();
  for (int p = 0; p < np; p++) {
    const double *xi = x + 3 * PI[p], *xj = x + 3 * PJ[p];
    const double d0 = xj[0] - xi[0], d1 = xj[1] - xi[1], d2 = xj[2] - xi[2];
    E[p] = std::sqrt(d0 * d0 + d1 * d1 + d2 * d2) - L[p];
    P[p] = 0.0;
  }
  const int nt = (int) tkappa.size();
  const int *__restrict TP = tptr.data(), *__restrict TQ = tpair.data();
  const double *__restrict TV = tval.data(), *__restrict K = tkappa.data();
  for (int m = 0; m < nt; m++) {
    double th = 0.0;
    for (int k = TP[m]; k < TP[m + 1]; k++) th += TV[k] * E[TQ[k]];
    const double t = K[m] * th;
    for (int k = TP[m]; k < TP[m + 1]; k++) P[TQ[k]] += t * TV[k];
  }
  const int nall = atom->nlocal + atom->nghost;
  fv.assign(3 * (size_t) nall, 0.0);
  double *__restrict F = fv.data();
  for (int p = 0; p < np; p++) {
    if (P[p] == 0.0) continue;
    const int i = PI[p], j = PJ[p];
    const double *xi = x + 3 * i, *xj = x + 3 * j;
    const double g = P[p] / (E[p] + L[p]);
    for (int k = 0; k < 3; k++) {
      const double w = g * (xj[k] - xi[k]);
      F[3 * i + k] += w;
      F[3 * j + k] -= w;
    }
  }
  // the partners' shares this rank computed as ghosts go to their owners
  if (comm->nprocs > 1) comm->reverse_comm(this);
  double *__restrict f = atom->f[0];
  const int nlocal = atom->nlocal;
  int *mask = atom->mask;
  for (int i = 0; i < nlocal; i++) {
    if (!(mask[i] & groupbit)) continue;
    const double *a3 = &fv[3 * i];
    if (!RackStress::finite3(a3)) {
      RackStress::nonfinite(lmp, "rs/volume", atom->tag[i]);
      continue;
    }
    const double m = RackStress::mass(atom, i);
    f[3 * i] += m * a3[0];
    f[3 * i + 1] += m * a3[1];
    f[3 * i + 2] += m * a3[2];
  }
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

void FixRSVolume::unpack_reverse_comm(int n, int *list, double *buf)
{
  int m = 0;
  for (int i = 0; i < n; i++) {
    const int j = list[i];
    fv[3 * j] += buf[m++];
    fv[3 * j + 1] += buf[m++];
    fv[3 * j + 2] += buf[m++];
  }
}
