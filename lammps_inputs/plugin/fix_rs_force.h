/* -*- c++ -*- ----------------------------------------------------------
   rackstress plugin: a constant force, Eq. 8
------------------------------------------------------------------------- */

#ifdef FIX_CLASS
// clang-format off
FixStyle(rs/force,FixRSForce);
// clang-format on
#else

#ifndef RS_FIX_FORCE_H
#define RS_FIX_FORCE_H

#include "fix.h"
#include "rs_common.h"

namespace LAMMPS_NS {

class FixRSForce : public Fix {
 public:
  FixRSForce(class LAMMPS *, int, char **);
  int setmask() override;
  void setup(int) override;
  void post_force(int) override;

 private:
  double fv[3];
  bool first_rows = false;    // the group lies in atom_modify's first group (rs_common.h)
};

}    // namespace LAMMPS_NS

#endif
#endif
