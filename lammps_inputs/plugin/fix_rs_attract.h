/* -*- c++ -*- ----------------------------------------------------------
   rackstress plugin: attract with index-matched regions, Eqs. 14, 27-28
------------------------------------------------------------------------- */

#ifdef FIX_CLASS
// clang-format off
FixStyle(rs/attract,FixRSAttract);
// clang-format on
#else

#ifndef RS_FIX_ATTRACT_H
#define RS_FIX_ATTRACT_H

#include "fix.h"
#include "rs_common.h"

namespace LAMMPS_NS {

class FixRSAttract : public Fix, public RackStress::Reduced {
 public:
  FixRSAttract(class LAMMPS *, int, char **);
  ~FixRSAttract() override;
  RackStress::Gathered *gathered() override { return &few; }
  int setmask() override;
  void init() override;
  void setup(int) override;
  void post_force(int) override;

 private:
  int sourcebit;
  double c;
  std::string tname, sname;    // region index names, empty: every pair (a constant c)
  bool ready;
  bool first_rows = false;    // the group lies in atom_modify's first group (rs_common.h)
  RackStress::Gathered few;
  std::vector<int> by_key_first, by_key;    // members grouped by region index
};

}    // namespace LAMMPS_NS

#endif
#endif
