/* -*- c++ -*- ----------------------------------------------------------
   rackstress plugin: directed collide, Eqs. 10-11
------------------------------------------------------------------------- */

#ifdef FIX_CLASS
// clang-format off
FixStyle(rs/collide,FixRSCollide);
// clang-format on
#else

#ifndef RS_FIX_COLLIDE_H
#define RS_FIX_COLLIDE_H

#include "fix.h"
#include "rs_common.h"

namespace LAMMPS_NS {

class FixRSCollide : public Fix {
 public:
  FixRSCollide(class LAMMPS *, int, char **);
  int setmask() override;
  void init() override;
  void setup(int) override;
  void post_force(int) override;

  void *extract(const char *, int &) override;

 private:
  int sourcebit;
  int actbit;       // the moving group of active-only integration (keyword activate), or 0
  double c;
  double mu, eta;   // friction MU ETA (0: frictionless)
  bool built, in_setup;
  int touching;
  RackStress::Contacts list;
};

}    // namespace LAMMPS_NS

#endif
#endif
