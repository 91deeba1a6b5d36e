/* -*- c++ -*- ----------------------------------------------------------
   rackstress plugin: the rack coupling, Eq. 23 (bind over every pair, Eqs. 12-13)
------------------------------------------------------------------------- */

#ifdef FIX_CLASS
// clang-format off
FixStyle(rs/rack,FixRSRack);
// clang-format on
#else

#ifndef RS_FIX_RACK_H
#define RS_FIX_RACK_H

#include "fix.h"
#include "rs_common.h"

namespace LAMMPS_NS {

class FixRSRack : public Fix, public RackStress::Reduced {
 public:
  FixRSRack(class LAMMPS *, int, char **);
  ~FixRSRack() override;
  RackStress::Gathered *gathered() override { return &few; }
  int partial_size() override;
  void partial(double *) override;
  void total(const double *) override;
  int setmask() override;
  void init() override;
  void setup(int) override;
  void post_force(int) override;

 private:
  int sourcebit;
  double c;
  bool gather_source;     // gather the smaller of the two groups on every rank
  bool ready;
  RackStress::Gathered few;
  std::vector<double> sums;
  // the owned rows of the side summed over (kept from one reneighbouring to the next), and
  // whether the two groups share atoms (a particle is never bound to itself)
  std::vector<int> rows;
  // L0² of each (owned row, gathered member) pair (constant: original positions), in the
  // order the sums visit them, with the member's own pair skipped (own = 1)
  std::vector<double> l0sq;
  std::vector<char> own;
  std::vector<double> l0t;      // l0sq transposed: [member][row]
  // the fused pass's per-member sums (3 per member)
  std::vector<double> lanesum;
  bool rows_built, overlap;
  // fused with the reverse coupling (rack <- host with host <- rack: Eq. 12's factor of a pair
  // is the same both ways but c): the fix that gathers its targets (the rack) computes both in
  // one pass, the other's accelerations per row into its `acc`, valid at step `acc_step`
  FixRSRack *reverse = nullptr;
  std::vector<double> acc;
  bigint acc_step = -1;
  FixRSRack *find_reverse();
  bool first_rows = false;    // the summed side lies in atom_modify's first group (rs_common.h)
  const std::vector<int> &owned_rows();
};

}    // namespace LAMMPS_NS

#endif
#endif
