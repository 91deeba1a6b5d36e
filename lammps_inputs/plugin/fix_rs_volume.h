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
  std::vector<int> btypes;
  bool built;
  // this rank's owned atoms of the group (atom-id order), their pairs (rows i, j, rest length
  // L, CSR over the atoms) and their terms (CSR of (pair, coefficient), κ per term): rebuilt
  // whenever LAMMPS reneighbours (the rows change; the terms do not)
  std::vector<int> rows, pi, pj, tptr, tpair;
  std::vector<double> pL, tval, tkappa, e, pull, fv;
  void collect();
};

}    // namespace LAMMPS_NS

#endif
#endif
