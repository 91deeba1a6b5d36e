/* -*- c++ -*- ----------------------------------------------------------
   rackstress plugin: directed bind with a per-pair L0, Eqs. 12-13 (within(d), Eq. 16)
------------------------------------------------------------------------- */

#ifdef FIX_CLASS
// clang-format off
FixStyle(rs/bind,FixRSBind);
// clang-format on
#else

#ifndef RS_FIX_BIND_H
#define RS_FIX_BIND_H

#include "fix.h"
#include "rs_common.h"

namespace LAMMPS_NS {

class FixRSBind : public Fix {
 public:
  FixRSBind(class LAMMPS *, int, char **);
  int setmask() override;
  void init() override;
  void setup(int) override;
  void post_force(int) override;

 private:
  int sourcebit, btype;
  double c;
};

}    // namespace LAMMPS_NS

#endif
#endif
