/* -*- c++ -*- ----------------------------------------------------------
   rackstress plugin: integrate, Eq. 5 (velocity Verlet over the moving rows)
------------------------------------------------------------------------- */

#ifdef FIX_CLASS
// clang-format off
FixStyle(rs/nve,FixRSNVE);
// clang-format on
#else

#ifndef RS_FIX_NVE_H
#define RS_FIX_NVE_H

#include "fix.h"
#include "rs_common.h"

#include <vector>

namespace LAMMPS_NS {

class FixRSNVE : public Fix {
 public:
  FixRSNVE(class LAMMPS *, int, char **);
  int setmask() override;
  void init() override;
  void setup(int) override;
  void setup_pre_neighbor() override;
  void pre_neighbor() override;
  void initial_integrate(int) override;
  void post_integrate() override;
  void final_integrate() override;
  void reset_dt() override;

 private:
  double dtv, dtf;
  std::vector<double> dtfm;    // dtf / m of each atom type (per-type masses)
  bool first_rows = false;     // the group lies in atom_modify's first group (rs_common.h)
  // the displacement check (neigh_modify ... check no once yes hands it to this fix): the
  // positions of the rows it integrates when LAMMPS last reneighboured
  bool check = false;
  std::vector<double> xhold;
  void hold(int n);
};

}    // namespace LAMMPS_NS

#endif
#endif
