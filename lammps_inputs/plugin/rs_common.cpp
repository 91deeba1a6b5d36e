/* rackstress plugin: shared helpers (rs_common.h). */

#include "rs_common.h"

#include "domain.h"
#include "group.h"
#include "neighbor.h"
#include "update.h"

#include <chrono>
#include <climits>
#include <cstdint>
#include <cstdio>
#include <map>

#include <algorithm>
#include <cmath>
#include <thread>

using namespace LAMMPS_NS;
using namespace RackStress;

double **RackStress::originals(Atom *atom, Error *error, const char *style)
{
  int flag, cols;
  int idx = atom->find_custom("rso", flag, cols);
  if (idx < 0 || flag != 1 || cols != 3)
    error->all(FLERR, "Fix {}: needs the original positions as per-atom d2_rso 3 (fix "
               "property/atom d2_rso 3 ghost yes, filled by read_data)", style);
  return atom->darray[idx];
}

double *RackStress::radii(Atom *atom, Error *error, const char *style)
{
  int flag, cols;
  int idx = atom->find_custom("rsr", flag, cols);
  if (idx < 0 || flag != 1 || cols != 0)
    error->all(FLERR, "Fix {}: needs the radii as per-atom d_rsr (fix property/atom d_rsr "
               "ghost yes, filled by read_data)", style);
  return atom->dvector[idx];
}

int *RackStress::ivector(Atom *atom, Error *error, const char *style, const std::string &name)
{
  int flag, cols;
  int idx = atom->find_custom(name.c_str(), flag, cols);
  if (idx < 0 || flag != 0 || cols != 0)
    error->all(FLERR, "Fix {}: region index i_{} is not a per-atom integer property (fix "
               "property/atom i_{} ghost yes)", style, name, name);
  return atom->ivector[idx];
}

int RackStress::groupbit(Group *group, Error *error, const char *style, const char *what,
                         const char *name)
{
  int g = group->find(name);
  if (g < 0) error->all(FLERR, "Fix {}: {} group '{}' does not exist", style, what, name);
  return group->bitmask[g];
}

/* ---------------------------------------------------------------------- */

void Gathered::collect(LAMMPS *lmp, int bit, const int *keys)
{
  Atom *atom = lmp->atom;
  MPI_Comm world = lmp->world;
  std::vector<tagint> mine;
  std::vector<int> mykeys;
  for (int i = 0; i < atom->nlocal; i++)
    if ((atom->mask[i] & bit) && (!keys || keys[i] != 0)) {
      mine.push_back(atom->tag[i]);
      mykeys.push_back(keys ? keys[i] : 0);
    }
  int nprocs;
  MPI_Comm_size(world, &nprocs);
  int n = (int) mine.size();
  std::vector<int> counts(nprocs), displs(nprocs, 0);
  MPI_Allgather(&n, 1, MPI_INT, counts.data(), 1, MPI_INT, world);
  for (int p = 1; p < nprocs; p++) displs[p] = displs[p - 1] + counts[p - 1];
  int total = displs[nprocs - 1] + counts[nprocs - 1];
  std::vector<tagint> alltags(total);
  std::vector<int> allkeys(total);
  MPI_Allgatherv(mine.data(), n, MPI_LMP_TAGINT, alltags.data(), counts.data(), displs.data(),
                 MPI_LMP_TAGINT, world);
  MPI_Allgatherv(mykeys.data(), n, MPI_INT, allkeys.data(), counts.data(), displs.data(),
                 MPI_INT, world);
  std::vector<int> order(total);
  for (int k = 0; k < total; k++) order[k] = k;
  std::sort(order.begin(), order.end(), [&](int a, int b) { return alltags[a] < alltags[b]; });
  tag.resize(total);
  key.resize(total);
  for (int k = 0; k < total; k++) {
    tag[k] = alltags[order[k]];
    key[k] = allkeys[order[k]];
  }
  // original positions, once
  double **orig = originals(atom, lmp->error, "rs");
  buf.assign(3 * total, 0.0);
  for (int k = 0; k < total; k++) {
    int m = atom->map(tag[k]);
    if (m >= 0 && m < atom->nlocal)
      for (int d = 0; d < 3; d++) buf[3 * k + d] = orig[m][d];
  }
  o.assign(3 * total, 0.0);
  MPI_Allreduce(buf.data(), o.data(), 3 * total, MPI_DOUBLE, MPI_SUM, world);
  x.assign(3 * total, 0.0);
}

void Gathered::fill(LAMMPS *lmp, double *into) const
{
  Atom *atom = lmp->atom;
  double **xx = atom->x;
  int n = size();
  for (int k = 0; k < n; k++) {
    int m = atom->map(tag[k]);
    if (m >= 0 && m < atom->nlocal)
      for (int d = 0; d < 3; d++) into[3 * k + d] = xx[m][d];
  }
}

/* ---------------------------------------------------------------------- */

namespace {
/* the resting atoms (owned rows past atom->nfirst, serial) binned once after a setup by their
   positions then, which they keep until LAMMPS reorders them among the first rows */
struct RestGrid {
  bool valid = false;
  double lo[3] = {0.0, 0.0, 0.0}, w = 1.0;
  int nb[3] = {1, 1, 1};
  std::vector<int> start;         // CSR over the cells
  std::vector<tagint> tags;
  std::vector<int> cellof;        // scratch of a build, kept (no fresh pages at the next one)
  std::vector<uint64_t> member;   // one bit per atom id: binned here
  // the layout the last check found the grid holding every resting row in (a setup's fixes
  // check once: the step, owned and first rows)
  bigint checked_step = -1;
  int checked_nlocal = -1, checked_nfirst = -1;
};
/* what a full pass over every atom found for a pair of sides (Contacts::collect_full), over all
   ranks: kept for the setups after it, which then pass over the moving rows and the grid */
struct Known {
  bool fast = false;
  double tmax = 0.0, smax = 0.0;
};
struct Registry {
  std::vector<Reduced *> members;
  bigint pos_step = -1, sum_step = -1;
  bool moved = false;    // the displacement flag reduce_positions carried at pos_step
  std::vector<double> send, recv;
  RestGrid rest;
  std::map<std::vector<int>, Known> known;    // (tbit, sbit, actbit, firstbit)
};
std::map<LAMMPS *, Registry> registry;
}    // namespace

void RackStress::enroll(LAMMPS *lmp, Reduced *r)
{
  Registry &reg = registry[lmp];
  if (std::find(reg.members.begin(), reg.members.end(), r) == reg.members.end())
    reg.members.push_back(r);
  reg.pos_step = reg.sum_step = -1;
}

void RackStress::leave(LAMMPS *lmp, Reduced *r)
{
  auto it = registry.find(lmp);
  if (it == registry.end()) return;
  auto &m = it->second.members;
  m.erase(std::remove(m.begin(), m.end(), r), m.end());
  it->second.pos_step = it->second.sum_step = -1;
  if (m.empty()) registry.erase(it);
}

void RackStress::invalidate(LAMMPS *lmp)
{
  Registry &reg = registry[lmp];
  reg.pos_step = reg.sum_step = -1;
}

bool RackStress::reduce_positions(LAMMPS *lmp, int moved)
{
  Registry &reg = registry[lmp];
  bigint now = lmp->update->ntimestep;
  if (reg.pos_step == now) return reg.moved;
  size_t n = 0;
  for (Reduced *r : reg.members)
    if (Gathered *g = r->gathered()) n += 3 * g->size();
  // the displacement flag rides as one more double (0 or 1 per rank: summed, exact)
  reg.send.assign(n + 1, 0.0);
  reg.recv.assign(n + 1, 0.0);
  size_t at = 0;
  for (Reduced *r : reg.members)
    if (Gathered *g = r->gathered()) {
      g->fill(lmp, reg.send.data() + at);
      at += 3 * g->size();
    }
  reg.send[n] = moved ? 1.0 : 0.0;
  if (lmp->comm->nprocs > 1)
    MPI_Allreduce(reg.send.data(), reg.recv.data(), (int) n + 1, MPI_DOUBLE, MPI_SUM, lmp->world);
  else
    reg.recv = reg.send;
  at = 0;
  for (Reduced *r : reg.members)
    if (Gathered *g = r->gathered()) {
      std::copy(reg.recv.begin() + at, reg.recv.begin() + at + 3 * g->size(), g->x.begin());
      at += 3 * g->size();
    }
  reg.moved = reg.recv[n] > 0.0;
  reg.pos_step = now;
  return reg.moved;
}

void RackStress::reduce_sums(LAMMPS *lmp)
{
  reduce_positions(lmp);
  Registry &reg = registry[lmp];
  bigint now = lmp->update->ntimestep;
  if (reg.sum_step == now) return;
  size_t n = 0;
  for (Reduced *r : reg.members) n += r->partial_size();
  reg.send.assign(n, 0.0);
  reg.recv.assign(n, 0.0);
  size_t at = 0;
  for (Reduced *r : reg.members) {
    r->partial(reg.send.data() + at);
    at += r->partial_size();
  }
  if (n) MPI_Allreduce(reg.send.data(), reg.recv.data(), (int) n, MPI_DOUBLE, MPI_SUM, lmp->world);
  at = 0;
  for (Reduced *r : reg.members) {
    r->total(reg.recv.data() + at);
    at += r->partial_size();
  }
  reg.sum_step = now;
}

bool RackStress::in_first(LAMMPS *lmp, int bit)
{
  Atom *atom = lmp->atom;
  if (!atom->firstgroupname) return false;
  int firstbit = lmp->group->bitmask[atom->firstgroup];
  int mine = 1, all = 0;
  for (int i = 0; i < atom->nlocal; i++)
    if ((atom->mask[i] & bit) && !(atom->mask[i] & firstbit)) {
      mine = 0;
      break;
    }
  MPI_Allreduce(&mine, &all, 1, MPI_INT, MPI_MIN, lmp->world);
  return all != 0;
}

/* every owned target with `tbit` and every owned or ghost source with `sbit`, and the largest
   radius of each side; whether later builds may pass over the moving rows only: when one side
   lies wholly in the first group (atoms outside it rest, and two resting atoms never form a pair
   anything needs: neither is integrated, a resting target is activated only by a moving source).
   Under MPI the ghosts are few (a shell one cutoff thick): later builds take every ghost source
   and the owned resting atoms near the moving owned and ghost rows (collect_moving). */
void Contacts::collect_full(LAMMPS *lmp, int tbit, int sbit, const double *radius, int actbit,
                            std::vector<int> &tcand, std::vector<int> &scand)
{
  Atom *atom = lmp->atom;
  int *mask = atom->mask;
  int nlocal = atom->nlocal, nall = atom->nlocal + atom->nghost;
  int firstbit = atom->firstgroupname ? lmp->group->bitmask[atom->firstgroup] : 0;
  bool t_first = true, s_first = true;
  tmax_all = smax_all = 0.0;
  for (int j = 0; j < nall; j++) {
    int m = mask[j];
    if (!(m & (tbit | sbit))) continue;
    if ((m & tbit) && j < nlocal) {
      tcand.push_back(j);
      tmax_all = std::max(tmax_all, radius[j]);
      if (!(m & firstbit)) t_first = false;
    }
    if (m & sbit) {
      scand.push_back(j);
      smax_all = std::max(smax_all, radius[j]);
      if (!(m & firstbit)) s_first = false;
    }
  }
  // over all ranks: a side lies in the first group if it does on every rank, and the reach of
  // a later build must cover an atom that arrives from a rank where the side's largest is
  double mx[2] = {tmax_all, smax_all}, gmx[2];
  MPI_Allreduce(mx, gmx, 2, MPI_DOUBLE, MPI_MAX, lmp->world);
  tmax_all = gmx[0];
  smax_all = gmx[1];
  int firsts[2] = {t_first ? 1 : 0, s_first ? 1 : 0}, gfirsts[2];
  MPI_Allreduce(firsts, gfirsts, 2, MPI_INT, MPI_MIN, lmp->world);
  fast = firstbit && (actbit == 0 || actbit == firstbit) && (gfirsts[0] || gfirsts[1]);
  Known &k = registry[lmp].known[{tbit, sbit, actbit, firstbit}];
  k.fast = fast;
  k.tmax = tmax_all;
  k.smax = smax_all;
}

/* whether the grid of resting atoms holds every owned resting row (at or past nfirst) of this
   rank: a resting atom does not move, but under MPI one may arrive by exchange (a subdomain's
   bounds follow a shrink-wrapped box); checked at each setup, once for all its fixes (a pass
   over the resting rows' ids, no positions); if one is missing the grid is binned again */
static bool rest_grid_holds(LAMMPS *lmp, RestGrid &g)
{
  Atom *atom = lmp->atom;
  if (!g.valid) return false;
  bigint now = lmp->update->ntimestep;
  if (g.checked_step == now && g.checked_nlocal == atom->nlocal && g.checked_nfirst == atom->nfirst)
    return true;
  const tagint *tag = atom->tag;
  const size_t nbits = 64 * g.member.size();
  bool ok = true;
  for (int j = atom->nfirst; j < atom->nlocal && ok; j++) {
    size_t t = (size_t) tag[j];
    ok = t < nbits && ((g.member[t >> 6] >> (t & 63)) & 1);
  }
  if (!ok) return false;
  g.checked_step = now;
  g.checked_nlocal = atom->nlocal;
  g.checked_nfirst = atom->nfirst;
  return true;
}

/* the moving rows [0, nfirst) of each side, every ghost source, and the owned resting atoms of
   a side within `cut` of the other side's moving rows, owned or ghost (from the grid of owned
   resting atoms: they never move, so they stay on this rank and in their cells until a setup;
   a ghost's mask is its owner's at the last reneighbouring, and an atom activated since cannot
   move before the next one) */
void Contacts::collect_moving(LAMMPS *lmp, int tbit, int sbit, std::vector<int> &tcand,
                              std::vector<int> &scand, double cut)
{
  Atom *atom = lmp->atom;
  double **x = atom->x;
  int *mask = atom->mask;
  int nfirst = atom->nfirst, nlocal = atom->nlocal, nall = nlocal + atom->nghost;
  int firstbit = lmp->group->bitmask[atom->firstgroup];
  double tlo[3] = {INFINITY, INFINITY, INFINITY}, thi[3] = {-INFINITY, -INFINITY, -INFINITY};
  double slo[3] = {INFINITY, INFINITY, INFINITY}, shi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (int j = 0; j < nfirst; j++) {
    int m = mask[j];
    if (m & tbit) {
      tcand.push_back(j);
      for (int d = 0; d < 3; d++) {
        tlo[d] = std::min(tlo[d], x[j][d]);
        thi[d] = std::max(thi[d], x[j][d]);
      }
    }
    if (m & sbit) {
      scand.push_back(j);
      for (int d = 0; d < 3; d++) {
        slo[d] = std::min(slo[d], x[j][d]);
        shi[d] = std::max(shi[d], x[j][d]);
      }
    }
  }
  // ghosts (none serially): every source is a candidate; a moving one also widens the box
  // around which the owned resting targets are taken (a ghost is never a target: targets are
  // owned)
  for (int j = nlocal; j < nall; j++) {
    int m = mask[j];
    if (!(m & sbit)) continue;
    scand.push_back(j);
    if (m & firstbit)
      for (int d = 0; d < 3; d++) {
        slo[d] = std::min(slo[d], x[j][d]);
        shi[d] = std::max(shi[d], x[j][d]);
      }
  }
  RestGrid &g = registry[lmp].rest;
  if (!g.valid) {
    // bin every resting row by its position (cells about one reach wide, not many more cells
    // than atoms)
    int n = nlocal - nfirst;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int j = nfirst; j < nlocal; j++)
      for (int d = 0; d < 3; d++) {
        lo[d] = std::min(lo[d], x[j][d]);
        hi[d] = std::max(hi[d], x[j][d]);
      }
    g.w = cut > 0.0 ? cut : 1.0;
    if (n == 0)
      for (int d = 0; d < 3; d++) lo[d] = hi[d] = 0.0;
    while (true) {
      double cells = 1.0;
      for (int d = 0; d < 3; d++) {
        g.nb[d] = (int) ((hi[d] - lo[d]) / g.w) + 1;
        cells *= g.nb[d];
      }
      if (cells <= 2.0 * n + 64.0) break;
      g.w *= 1.5;
    }
    for (int d = 0; d < 3; d++) g.lo[d] = lo[d];
    long ncell = (long) g.nb[0] * g.nb[1] * g.nb[2];    // at most 2 n + 64: an int
    const double inv = 1.0 / g.w;
    g.cellof.resize(n);
    g.start.assign(ncell + 1, 0);
    for (int j = nfirst; j < nlocal; j++) {
      int c = 0;
      for (int d = 0; d < 3; d++) {
        int k = std::max(0, std::min(g.nb[d] - 1, (int) ((x[j][d] - g.lo[d]) * inv)));
        c = c * g.nb[d] + k;
      }
      g.cellof[j - nfirst] = c;
      g.start[c + 1]++;
    }
    for (long c = 0; c < ncell; c++) g.start[c + 1] += g.start[c];
    // placed from the back of each cell (counts down to its start), so no copy of the starts
    g.tags.resize(n);
    g.member.assign((size_t) (atom->map_tag_max >> 6) + 1, 0);
    for (int j = nlocal - 1; j >= nfirst; j--) {
      const tagint t = atom->tag[j];
      g.tags[--g.start[g.cellof[j - nfirst] + 1]] = t;
      g.member[(size_t) t >> 6] |= (uint64_t) 1 << (t & 63);
    }
    // (each cell's end counted down to its start: shift back to starts)
    for (long c = 0; c < ncell; c++) g.start[c] = g.start[c + 1];
    g.start[ncell] = n;
    g.valid = true;
    g.checked_step = lmp->update->ntimestep;
    g.checked_nlocal = nlocal;
    g.checked_nfirst = nfirst;
  }
  // the resting atoms of `bit` in the cells that meet the box [lo - cut, hi + cut]
  auto near = [&](const double *lo, const double *hi, int bit, std::vector<int> &out) {
    if (!(lo[0] <= hi[0])) return;    // no moving atom on the other side
    int a[3], b[3];
    for (int d = 0; d < 3; d++) {
      a[d] = std::max(0, (int) std::floor((lo[d] - cut - g.lo[d]) / g.w));
      b[d] = std::min(g.nb[d] - 1, (int) std::floor((hi[d] + cut - g.lo[d]) / g.w));
      if (a[d] > b[d]) return;
    }
    for (int i = a[0]; i <= b[0]; i++)
      for (int j = a[1]; j <= b[1]; j++)
        for (int k = a[2]; k <= b[2]; k++) {
          long c = ((long) i * g.nb[1] + j) * g.nb[2] + k;
          for (int n = g.start[c]; n < g.start[c + 1]; n++) {
            int m = atom->map(g.tags[n]);
            // a row before nfirst was put among the moving ones: the pass above has it
            if (m >= nfirst && m < nlocal && (mask[m] & bit)) out.push_back(m);
          }
        }
  };
  near(slo, shi, tbit, tcand);
  near(tlo, thi, sbit, scand);
}


/* ---------------------------------------------------------------------- */

namespace {
struct FirstBad {
  bool watched = false;     // a rackstress run: record; else (plain lmp) stop LAMMPS
  bigint step = -1;
  tagint tag = 0;
};
std::map<LAMMPS *, FirstBad> first_bad;
}    // namespace

void RackStress::nonfinite(LAMMPS *lmp, const char *style, tagint tag)
{
  FirstBad &b = first_bad[lmp];
  bigint now = lmp->update->ntimestep;
  if (!b.watched) {
    const std::string mesg = fmt::format(
        "Fix {}: the force on atom id {} is not finite at step {}: two particles bound or "
        "attracted to each other coincide there (Eq. 12's direction is undefined at d = 0), or "
        "a force overflowed; a smaller time step or weaker coefficients keep Eq. 5 stable",
        style, (bigint) tag, now);
    // error->one writes on rank 0's buffered screen only (a null screen elsewhere), then
    // MPI_Abort, and mpiexec's proxies stop forwarding the ranks' output as they tear the job
    // down: on a busy machine nothing reached the terminal (stdout cut at its last flush, no
    // stderr). Each rank says it on stderr, flushes, and under MPI gives mpiexec a second to
    // forward it before the abort (only a run that is ending pays it).
    if (lmp->screen) fflush(lmp->screen);
    if (lmp->comm->nprocs > 1) {
      fprintf(stderr, "ERROR on proc %d: %s\n", lmp->comm->me, mesg.c_str());
      fflush(stderr);
      std::this_thread::sleep_for(std::chrono::seconds(1));
    }
    lmp->error->one(FLERR, mesg);
  }
  if (b.step < 0 || (now == b.step && tag < b.tag)) {
    b.step = now;
    b.tag = tag;
  }
}

/* The runner's side (called through ctypes on the loaded plugin, with the `lammps` module's
   handle, which is the LAMMPS instance). rackstress_watch: this instance records non-finite
   terms instead of stopping (and forgets an earlier instance's record at the same address).
   rackstress_first_nonfinite: collective; the first step any rank recorded and, of that step,
   the smallest atom id; returns 0 if none. rackstress_nonfinite_here: this rank's record alone
   (its step, or -1), no communication: the runner folds it into the one reduction of its
   watchdog check and asks the collective only when a rank has one. */
extern "C" __attribute__((visibility("default"))) void rackstress_watch(void *handle)
{
  FirstBad &b = first_bad[(LAMMPS *) handle];
  b = FirstBad();
  b.watched = true;
}

extern "C" __attribute__((visibility("default"))) long long
rackstress_nonfinite_here(void *handle)
{
  auto it = first_bad.find((LAMMPS *) handle);
  return (it != first_bad.end() && it->second.step >= 0) ? (long long) it->second.step : -1;
}

extern "C" __attribute__((visibility("default"))) int
rackstress_first_nonfinite(void *handle, long long *step, long long *tag)
{
  LAMMPS *lmp = (LAMMPS *) handle;
  auto it = first_bad.find(lmp);
  bool mine = it != first_bad.end() && it->second.step >= 0;
  long long s = mine ? (long long) it->second.step : LLONG_MAX, all_s, t, all_t;
  MPI_Allreduce(&s, &all_s, 1, MPI_LONG_LONG, MPI_MIN, lmp->world);
  if (all_s == LLONG_MAX) return 0;
  t = (mine && s == all_s) ? (long long) it->second.tag : LLONG_MAX;
  MPI_Allreduce(&t, &all_t, 1, MPI_LONG_LONG, MPI_MIN, lmp->world);
  *step = all_s;
  *tag = all_t;
  return 1;
}

int Contacts::build(LAMMPS *lmp, int tbit, int sbit, const double *radius, int actbit, bool full)
{
  Atom *atom = lmp->atom;
  double **x = atom->x, **f = atom->f;
  int *mask = atom->mask;
  double skin = lmp->neighbor->skin;
  // activation looks one skin further than the contact candidates
  double wide = actbit ? 2.0 * skin : skin;
  int activated = 0;

  // each side cut to the other's bounding box grown by the reach (a leg meets a few hundred of
  // a sediment's particles, not all): a target left out is farther than r_max + skin from every
  // source, so nothing reaches it before LAMMPS reneighbours
  rows.clear();
  near_valid = false;
  std::vector<int> src, tcand, scand;
  if (full && atom->firstgroupname) {
    // a setup: what an earlier full pass found for these sides still holds (a side in the
    // first group stays there: an atom never leaves it; radii do not change), so it passes
    // over the moving rows and the grid of resting atoms, if the grid still holds every
    // resting row (each setup's fixes agree: the check is collective)
    Registry &reg = registry[lmp];
    auto it = reg.known.find({tbit, sbit, actbit, lmp->group->bitmask[atom->firstgroup]});
    if (it != reg.known.end() && it->second.fast) {
      int mine = rest_grid_holds(lmp, reg.rest) ? 1 : 0, all = 0;
      MPI_Allreduce(&mine, &all, 1, MPI_INT, MPI_MIN, lmp->world);
      if (!all) reg.rest.valid = false;    // binned again by collect_moving
      fast = true;
      tmax_all = it->second.tmax;
      smax_all = it->second.smax;
      full = false;
    }
  }
  if (full || !fast || !atom->firstgroupname)
    collect_full(lmp, tbit, sbit, radius, actbit, tcand, scand);
  else
    collect_moving(lmp, tbit, sbit, tcand, scand, tmax_all + smax_all + wide);
  double smax = smax_all, tmax = tmax_all;
  double tlo[3] = {INFINITY, INFINITY, INFINITY}, thi[3] = {-INFINITY, -INFINITY, -INFINITY};
  double slo[3] = {INFINITY, INFINITY, INFINITY}, shi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (int j : tcand)
    for (int d = 0; d < 3; d++) {
      tlo[d] = std::min(tlo[d], x[j][d]);
      thi[d] = std::max(thi[d], x[j][d]);
    }
  for (int j : scand)
    for (int d = 0; d < 3; d++) {
      slo[d] = std::min(slo[d], x[j][d]);
      shi[d] = std::max(shi[d], x[j][d]);
    }
  double cut = tmax + smax + wide;
  auto within = [&](const double *p, const double *lo, const double *hi) {
    return p[0] > lo[0] - cut && p[0] < hi[0] + cut && p[1] > lo[1] - cut &&
        p[1] < hi[1] + cut && p[2] > lo[2] - cut && p[2] < hi[2] + cut;
  };
  for (int j : scand)
    if (within(x[j], tlo, thi)) src.push_back(j);
  double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (int i : tcand)
    if (within(x[i], slo, shi)) {
      rows.push_back(i);
      for (int d = 0; d < 3; d++) {
        lo[d] = std::min(lo[d], x[i][d]);
        hi[d] = std::max(hi[d], x[i][d]);
      }
    }
  first.assign(rows.size() + 1, 0);
  partner.clear();
  // the atoms whose moves can bring a candidate pair closer: every one but the owned resting
  // rows (at or past nfirst: not integrated before LAMMPS reneighbours and this list is built
  // again, rs_common.h "Resting atoms"), which on a bed are most of the sources
  watch.clear();
  const int nfirst = atom->firstgroupname ? atom->nfirst : atom->nlocal, nlocal = atom->nlocal;
  for (int j : rows)
    if (j < nfirst || j >= nlocal) watch.push_back(j);
  for (int j : src)
    if (j < nfirst || j >= nlocal) watch.push_back(j);
  if (rows.empty() || src.empty()) return 0;

  // a cell grid over the sources near the targets, cells one reach wide
  // (cells at least one reach wide, so a target's partners are in its 27 cells; widened
  // until there are not many more cells than sources)
  int nb[3];
  double w = cut;
  for (int d = 0; d < 3; d++) lo[d] -= cut;
  while (true) {
    double cells = 1.0;
    for (int d = 0; d < 3; d++) {
      nb[d] = (int) ((hi[d] + cut - lo[d]) / w) + 1;
      cells *= nb[d];
    }
    if (cells <= 8.0 * src.size() + 64.0) break;
    w *= 1.5;
  }
  auto cell = [&](const double *p, int d) {
    int c = (int) ((p[d] - lo[d]) / w);
    return std::max(0, std::min(nb[d] - 1, c));
  };
  long ncell = (long) nb[0] * nb[1] * nb[2];
  std::vector<int> head(ncell, -1), next(src.size(), -1);
  for (int k = (int) src.size() - 1; k >= 0; k--) {
    const double *p = x[src[k]];
    long c = ((long) cell(p, 0) * nb[1] + cell(p, 1)) * nb[2] + cell(p, 2);
    next[k] = head[c];
    head[c] = k;
  }
  for (size_t r = 0; r < rows.size(); r++) {
    int i = rows[r];
    const double *p = x[i];
    double reach = radius[i] + smax + skin, reach2 = reach * reach;
    bool resting = actbit && !(mask[i] & actbit);
    int c0[3];
    for (int d = 0; d < 3; d++) c0[d] = cell(p, d);
    for (int a = std::max(0, c0[0] - 1); a <= std::min(nb[0] - 1, c0[0] + 1); a++)
      for (int b = std::max(0, c0[1] - 1); b <= std::min(nb[1] - 1, c0[1] + 1); b++)
        for (int e = std::max(0, c0[2] - 1); e <= std::min(nb[2] - 1, c0[2] + 1); e++)
          for (int k = head[((long) a * nb[1] + b) * nb[2] + e]; k >= 0; k = next[k]) {
            int j = src[k];
            if (atom->tag[j] == atom->tag[i]) continue;
            double dx = x[j][0] - p[0], dy = x[j][1] - p[1], dz = x[j][2] - p[2];
            double d2 = dx * dx + dy * dy + dz * dz;
            if (d2 < reach2) partner.push_back(j);
            if (resting && (mask[j] & actbit)) {
              double act = radius[i] + radius[j] + 2.0 * skin;
              if (d2 < act * act) {
                mask[i] |= actbit;
                // a resting row's force is whatever its row last held (LAMMPS moves positions
                // and velocities with an atom, not forces, and with neigh_modify include clears
                // only the first rows): zero it, so that until LAMMPS puts the atom among the
                // first rows (whose forces it clears each step) the phase switch's velocity
                // shift (v - dt/2 f/m over the moving group) leaves it at rest; a setup's
                // contact force is added to it below
                f[i][0] = f[i][1] = f[i][2] = 0.0;
                resting = false;
                activated++;
              }
            }
          }
    first[r + 1] = (int) partner.size();
    tagint *tag = atom->tag;
    std::sort(partner.begin() + first[r], partner.end(),
              [tag](int a, int b) { return tag[a] < tag[b]; });
  }
  return activated;
}

void Contacts::refresh(LAMMPS *lmp, const double *radius, double s)
{
  double **x = lmp->atom->x;
  const size_t n = watch.size();
  if (near_valid) {
    const double lim2 = 0.25 * s * s;
    bool moved = false;
    for (size_t k = 0; k < n && !moved; k++) {
      const double *p = x[watch[k]], *q = &x0[3 * k];
      double dx = p[0] - q[0], dy = p[1] - q[1], dz = p[2] - q[2];
      moved = dx * dx + dy * dy + dz * dz > lim2;
    }
    if (!moved) return;
  }
  x0.resize(3 * n);
  for (size_t k = 0; k < n; k++)
    for (int d = 0; d < 3; d++) x0[3 * k + d] = x[watch[k]][d];
  near_rows.clear();
  near_first.assign(1, 0);
  near_partner.clear();
  for (size_t k = 0; k < rows.size(); k++) {
    int i = rows[k];
    const double *p = x[i];
    for (int m = first[k]; m < first[k + 1]; m++) {
      int j = partner[m];
      double dx = x[j][0] - p[0], dy = x[j][1] - p[1], dz = x[j][2] - p[2];
      double reach = radius[i] + radius[j] + s;
      if (dx * dx + dy * dy + dz * dz < reach * reach) near_partner.push_back(j);
    }
    if ((int) near_partner.size() > near_first.back()) {
      near_rows.push_back((int) k);
      near_first.push_back((int) near_partner.size());
    }
  }
  near_valid = true;
}
