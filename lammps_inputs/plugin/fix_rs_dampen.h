/* -*- c++ -*- ----------------------------------------------------------
   rackstress plugin: conditional dampen, Eq. 28 (Eq. 9 while a contact holds)
------------------------------------------------------------------------- */

#ifdef FIX_CLASS
// clang-format off
FixStyle(rs/dampen,FixRSDampen);
// clang-format on
#else

#ifndef RS_FIX_DAMPEN_H
#define RS_FIX_DAMPEN_H

#include "fix.h"
#include "rs_common.h"

namespace LAMMPS_NS {

class FixRSDampen : public Fix, public RackStress::Reduced {
 public:
  FixRSDampen(class LAMMPS *, int, char **);
  ~FixRSDampen() override;
  int partial_size() override { return 1; }
  void partial(double *) override;
  void total(const double *) override;
  int setmask() override;
  void init() override;
  void setup(int) override;
  void post_force(int) override;

 private:
  int contactbit;
  double c;
  std::vector<double> ctype;    // c per atom type (c unless a type keyword gives its own)
  std::vector<double> gtype;    // c_T·m_T per type (post_force, per-type masses)
  bool built, ready, holds;
  bool first_rows = false;    // the group lies in atom_modify's first group (rs_common.h)
  RackStress::Contacts list;
};

}    // namespace LAMMPS_NS

#endif
#endif
