/* -*- c++ -*- ----------------------------------------------------------
   rackstress plugin: a material part's volumetric term (its Poisson's ratio)
------------------------------------------------------------------------- */

#ifdef FIX_CLASS
// clang-format off
FixStyle(rs/volume,FixRSVolume);
// clang-format on
#else

#ifndef RS_FIX_VOLUME_H
#define RS_FIX_VOLUME_H

#include "fix.h"
#include "rs_common.h"

#include <vector>

namespace LAMMPS_NS {

class FixRSVolume : public Fix {
 public:
  FixRSVolume(class LAMMPS *, int, char **);
  int setmask() override;
  void init() override;
  void setup(int) override;
  void post_force(int) override;
  int pack_reverse_comm(int, int, double *) override;
  void unpack_reverse_comm(int, int *, double *) override;

 private:
  double a, c[3], cmu;
  std::vector<int> btypes, bindtypes;
  std::vector<double> bindc;
  bool built;
  int nread;    // the pairs [0, nread) feed a strain, the rest are only bound
  // this rank's owned atoms of the group (atom-id order, `rows`), their strains z (D_0..2,
  // and G_0, G_1 on a face particle; mptr) and quadratic forms A (dense, aptr), and the pairs
  // (rows i, j, rest length L, L², the c this fix binds them with or 0) with the strains each
  // feeds (CSR qptr, qslot, qw): rebuilt whenever LAMMPS reneighbours
  std::vector<int> rows, pi, pj, mptr, aptr, qptr, qslot;
  std::vector<double> pL, pQ, pc, qw, amat, dist, dvec, z, y, fv;
  void collect();
};

}    // namespace LAMMPS_NS

#endif
#endif
