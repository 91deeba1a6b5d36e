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

#include <vector>

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
  bool built;
  // this rank's pairs of bond type btype, kept from one reneighbouring to the next: the rows,
  // L0² (from the original positions, once) and which end(s) gain the term (1: i1, 2: i2)
  std::vector<int> p1, p2, ends;
  std::vector<int> listers;    // owned atoms with bonds, in atom-id order (collect)
  std::vector<double> q;
  void collect();
};

}    // namespace LAMMPS_NS

#endif
#endif
