/* -*- c++ -*- ----------------------------------------------------------
   rackstress plugin: what the operator styles share.

   Every style adds the paper's *directed* acceleration (Rönkkö et al., Section 2.3) of the
   atoms a rank owns, as a force f = m·a (LAMMPS integrates f/m), from partners that are owned
   or ghost atoms there, or — for whole-body couplings (Eq. 23) and index-matched attraction
   (Eqs. 27–28) — from a small set of atoms gathered on every rank with one MPI_Allreduce a step,
   the way fix rigid sums its bodies. No reverse communication is needed, and the ghost cutoff
   is the real interaction range (a collision's reach, a bound pair's length).

   Per-atom data come from LAMMPS' own fix property/atom (ghost yes), filled by read_data:
     d2_rso[3]  original position o (Eq. 1), for L0 = ‖u_o − p_o‖ (Eq. 12)
     d_rsr      radius r (Eq. 1), for the collision reach R = r_p + r_u (Eq. 10)
     i_NAME     attraction region indices (Eqs. 27–28)
------------------------------------------------------------------------- */

#ifndef RS_COMMON_H
#define RS_COMMON_H

#include "atom.h"
#include "comm.h"
#include "error.h"
#include "group.h"
#include "lammps.h"
#include "pointers.h"

#include <cmath>
#include <mpi.h>
#include <algorithm>
#include <string>
#include <unordered_map>
#include <vector>

namespace LAMMPS_NS {
namespace RackStress {

  //! per-atom original positions o (fix property/atom d2_rso 3 ghost yes)
  double **originals(Atom *atom, Error *error, const char *style);
  //! per-atom radii r (fix property/atom d_rsr ghost yes)
  double *radii(Atom *atom, Error *error, const char *style);
  //! per-atom integer property i_NAME (attraction region indices)
  int *ivector(Atom *atom, Error *error, const char *style, const std::string &name);
  //! the group bit of a group named in a fix's arguments (error naming the keyword if missing)
  int groupbit(Group *group, Error *error, const char *style, const char *what, const char *name);

  inline double mass(Atom *atom, int i)
  {
    return atom->rmass ? atom->rmass[i] : atom->mass[atom->type[i]];
  }

  //! every atom's mass is 1 (per type, as every generated deck's): f = a, the same bits as 1·a
  inline bool unit_masses(Atom *atom)
  {
    if (atom->rmass) return false;
    for (int t = 1; t <= atom->ntypes; t++)
      if (atom->mass[t] != 1.0) return false;
    return true;
  }

  /* Eq. 12's pull per unit length of d: c·(1 − L0²/‖d‖²) — the acceleration on p from u is
     this times d = u − p. Every style that binds (rs/bind, rs/rack, rs/volume's bind) says it
     here once. */
  inline double eq12(double c, double L0sq, double d2)
  {
    return c * (1.0 - L0sq / d2);
  }

  /* A term that is not finite — Eq. 12's direction is 0/0 where a bound or attracted pair
     coincides (d = 0), or a force overflowed — is never added: LAMMPS' positions stay finite, and
     the step it arises in is the first bad one. In a run rackstress drives (rackstress_watch
     below), the first such (step, atom id) is kept for the runner's next watchdog check, which
     names it (exit 3, 'diverged', as the Python callback and the reference engine do); in a
     plain `lmp` run the style stops LAMMPS there with that message (error->one ends every
     rank). */
  inline bool finite3(const double *a)
  {
    return std::isfinite(a[0]) && std::isfinite(a[1]) && std::isfinite(a[2]);
  }
  void nonfinite(LAMMPS *, const char *style, tagint tag);

  /* A small set of atoms (a rack, an attraction region) known on every rank: their ids, their
     original positions (once) and their positions (each step, one MPI_Allreduce of a buffer
     each owner fills: every other rank adds zeros, so each position arrives exactly). */
  class Gathered {
   public:
    std::vector<tagint> tag;      // sorted atom ids
    std::vector<int> key;         // an integer per member (region index), 0 if none
    std::vector<double> o, x;     // 3 per member
    //! collect the owned atoms with `bit` (and key != 0 when keys is given), on every rank
    void collect(LAMMPS *lmp, int bit, const int *keys);
    //! this rank's share of the positions (the owners' rows, zeros elsewhere) into `into`
    void fill(LAMMPS *lmp, double *into) const;
    int size() const { return (int) tag.size(); }

   private:
    std::vector<double> buf;
  };
  class Reduced;

  /* What a style reduces over the ranks each step. Every style's reductions of one step are
     fused (all gathered positions in one MPI_Allreduce, then all partial sums and contact flags
     in one more), so a step costs two collectives however many racks, regions and contact
     conditions a scene has: ranks meet twice a step, not once per operator. */
  class Reduced {
   public:
    virtual ~Reduced() noexcept(false) = default;    // as LAMMPS' Fix
    virtual Gathered *gathered() { return nullptr; }    // positions to gather, if any
    virtual int partial_size() { return 0; }           // doubles of partial sums, if any
    virtual void partial(double *) {}                  // this rank's partial sums (phase 2)
    virtual void total(const double *) {}              // their sums over the ranks
  };
  void enroll(LAMMPS *, Reduced *);
  void leave(LAMMPS *, Reduced *);
  //! a fix's setup: the next request reduces again (same step, new state or new styles)
  void invalidate(LAMMPS *);
  /* this step's gathered positions of every enrolled style (one collective, once a step), with
     `moved` — whether an atom this rank integrates has moved half a skin since LAMMPS last
     reneighboured (fix rs/nve's displacement check, done in post_integrate before LAMMPS
     decides) — in the same collective: returns whether any rank's has. The first call of a step
     reduces; later calls of that step return the flag it carried. */
  bool reduce_positions(LAMMPS *, int moved = 0);
  //! this step's partial sums of every enrolled style (one collective, once a step)
  void reduce_sums(LAMMPS *);

  /* Candidate pairs (i owned with `tbit`, j owned or ghost with `sbit`) within the reach
     r_i + r_max(source) + skin, searched on a cell grid whenever LAMMPS reneighbours: no atom
     moves half a skin before the next, so no pair comes within r_i + r_j unseen (Eq. 11).
     Each target's partners are in atom-id order, so its sum does not depend on the rows LAMMPS
     gives the atoms (atom_modify first reorders them; active-only integration stays bit for bit).

     With `actbit` (the moving group of active-only integration, docs/model.md "Active
     particles"): a resting target (without `actbit`) that has a source with `actbit` within
     r_i + r_j + 2·skin is activated (`actbit` set in its mask), one reneighbouring before
     anything can touch it. Returns how many were activated. */
  class Contacts {
   public:
    std::vector<int> first, partner;    // CSR: partners of target i (owned rows)
    std::vector<int> rows;              // the owned target rows
    //! `full` (a fix's setup): pass over every owned and ghost atom; otherwise, where
    //! one side lies in the first group, over the moving rows, the ghosts and the owned
    //! resting atoms near the moving ones only (collect_moving; serial or MPI)
    int build(LAMMPS *lmp, int tbit, int sbit, const double *radius, int actbit = 0,
              bool full = true);

    /* The candidates within r_i + r_j + s, in the candidates' order (so each target's sum is
       the same, bit for bit): kept from step to step while no atom of the candidates moves more
       than s/2 from where it was when they were taken, and taken again from the candidates
       (not searched) when one does. Between two of LAMMPS' reneighbourings a step then passes
       over the pairs that can touch soon rather than over every candidate within a skin. */
    std::vector<int> near_rows, near_first, near_partner;    // CSR: index into rows, partners
    void refresh(LAMMPS *lmp, const double *radius, double s);

   private:
    std::vector<int> watch;        // the candidates' atoms (targets and sources)
    std::vector<double> x0;        // their positions when the near pairs were taken
    bool near_valid = false;
    double tmax_all = 0.0, smax_all = 0.0;    // largest radius of each side (the last full pass)
    bool fast = false;                         // whether a later build may leave the rest out
    void collect_full(LAMMPS *lmp, int tbit, int sbit, const double *radius, int actbit,
                      std::vector<int> &tcand, std::vector<int> &scand);
    void collect_moving(LAMMPS *lmp, int tbit, int sbit, std::vector<int> &tcand,
                        std::vector<int> &scand, double cut);
  };

  /* Resting atoms (docs/model.md "Active particles"): with `atom_modify first MOVING`, the deck
     integrates MOVING only (fix nve on it), so an owned row at or past atom->nfirst has not
     moved since LAMMPS last put the first group first; it joins MOVING for good and is
     reordered among the first rows at the next reneighbouring. A fix whose group lies in
     MOVING passes over rows [0, nfirst) only, not over every owned atom. */
  //! whether every atom of `bit` (on every rank) is in atom_modify's first group (a setup's pass)
  bool in_first(LAMMPS *lmp, int bit);
  //! the owned rows a fix whose group is `in_first` passes over: [0, nfirst), else [0, nlocal)
  inline int extent(Atom *atom, bool first) { return first ? atom->nfirst : atom->nlocal; }

  /* `rows` (owned rows below `limit`, each passing `keep`) put in atom-id order, so that a sum
     over them does not depend on the rows LAMMPS gave the atoms (exchanges, a resumed run's data
     file order): sorted if they are few, else read off the atom map (no n log n sort of a large
     host at each reneighbouring) */
  template <class Keep> void in_id_order(Atom *atom, int limit, std::vector<int> &rows, Keep keep)
  {
    tagint *tag = atom->tag;
    if ((bigint) rows.size() * 16 < (bigint) atom->map_tag_max) {
      std::sort(rows.begin(), rows.end(), [tag](int a, int b) { return tag[a] < tag[b]; });
      return;
    }
    rows.clear();
    for (tagint t = 1; t <= atom->map_tag_max; t++) {
      int i = atom->map(t);
      if (i >= 0 && i < limit && keep(i)) rows.push_back(i);
    }
  }

}    // namespace RackStress
}    // namespace LAMMPS_NS

#endif
