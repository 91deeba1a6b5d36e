/* -*- c++ -*- ----------------------------------------------------------
   rackstress plugin: a rigid spherical indenter, linear penalty ([[indenter]])
------------------------------------------------------------------------- */

#ifdef FIX_CLASS
// clang-format off
FixStyle(rs/indent,FixRSIndent);
// clang-format on
#else

#ifndef RS_FIX_INDENT_H
#define RS_FIX_INDENT_H

#include "fix.h"
#include "rs_common.h"

#include <string>

namespace LAMMPS_NS {

class FixRSIndent : public Fix {
 public:
  FixRSIndent(class LAMMPS *, int, char **);
  int setmask() override;
  void init() override;
  void setup(int) override;
  void min_setup(int) override;
  void post_force(int) override;
  void min_post_force(int) override;
  double compute_vector(int) override;

 private:
  double c0[3], travel[3], radius;
  bigint nsteps;               // the travel's steps (0: at c0 + travel from the start)
  double kconst;               // the stiffness per unit mass, or
  std::string kname;           // the per-atom property d_NAME holding it
  double ftotal[4], fall[4];   // this rank's force sum and the particles pushed; all ranks'
  bool summed;
};

}    // namespace LAMMPS_NS

#endif
#endif
