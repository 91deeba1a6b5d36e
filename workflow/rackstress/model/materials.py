"""Materials: Young's modulus E, Poisson's ratio ν, density and an optional yield strength.

Values are kept in SI and expressed in a scene's unit system on use
(:meth:`Material.in_units`). The presets are typical room-temperature values for a first look,
each with its source in ``source`` (and in docs); a scene that needs a particular grade gives its
own table.

Example
-------
>>> from rackstress.model.units import SYSTEMS
>>> al = material("aluminium")
>>> al.in_units(SYSTEMS["mm-N-s"])["E"], al.nu
(70000.0, 0.33)
"""
from __future__ import annotations

from dataclasses import dataclass

from rackstress.errors import SceneError
from rackstress.model.units import Units


#: What a material's E and density may be (SI): a decade or more beyond any solid's, so a
#: value outside is a slip of units or a typo, not a material.
RANGE = {"E": (1.0, 1e13, "Pa", "a soft gel is ~1e3 Pa, diamond 1.2e12 Pa"),
         "density": (1e-2, 1e5, "kg/m³", "an aerogel is ~1 kg/m³, osmium 22,590 kg/m³")}


@dataclass(frozen=True)
class Material:
    """A linear-elastic isotropic material, in SI: E [Pa], ν, density [kg/m³], yield [Pa]."""

    name: str
    E: float
    nu: float
    density: float
    yield_strength: float | None = None
    source: str = ""

    def __post_init__(self):
        where = f"material '{self.name}'"
        for key in ("E", "density"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and v > 0 and v < float("inf")):
                raise SceneError(f"{where}: {key} must be a positive number, got {v!r}")
            lo, hi, unit, known = RANGE[key]
            if not lo <= v <= hi:
                # 1e-300 or 1e300 would reach the solvers as subnormal or overflowing
                # coefficients (a NaN step, a static solve that cannot settle)
                raise SceneError(f"{where}: {key} = {v:g} {unit} is outside what any solid has "
                                 f"({lo:g} to {hi:g} {unit}; {known}); the material table is "
                                 "always SI, whatever the scene's units")
        if not (isinstance(self.nu, (int, float)) and -1.0 < self.nu < 0.5):
            raise SceneError(f"{where}: nu (Poisson's ratio) must lie in (-1, 0.5), got {self.nu!r}")
        y = self.yield_strength
        if y is not None and not (isinstance(y, (int, float)) and 0 < y < float("inf")):
            raise SceneError(f"{where}: yield must be a positive number, got {y!r}")

    def in_units(self, u: Units) -> dict:
        """E, nu, density and yield (None if not given) in the unit system ``u``."""
        return {"E": u.from_si("stress", self.E), "nu": self.nu,
                "density": u.from_si("density", self.density),
                "yield": None if self.yield_strength is None
                else u.from_si("stress", self.yield_strength)}


_MATWEB = "MatWeb material property data (matweb.com), typical values"
#: Preset materials by name (``material = "aluminium"``).
PRESETS = {m.name: m for m in (
    Material("steel", 200e9, 0.30, 7850.0, 250e6,
             "structural steel ASTM A36: E, nu, density, minimum yield; " + _MATWEB),
    Material("stainless-steel", 193e9, 0.29, 8000.0, 215e6,
             "AISI 304 annealed; " + _MATWEB),
    Material("aluminium", 70e9, 0.33, 2700.0, 276e6,
             "aluminium alloy 6061-T6 (E rounded from 68.9 GPa to the usual 70 GPa); " + _MATWEB),
    Material("titanium", 113.8e9, 0.342, 4430.0, 880e6,
             "Ti-6Al-4V (grade 5), annealed; " + _MATWEB),
    Material("ABS", 2.3e9, 0.35, 1040.0, 40e6,
             "ABS, general-purpose moulding grade (mid-range values); " + _MATWEB),
    Material("PLA", 3.5e9, 0.36, 1240.0, 60e6,
             "PLA, injection-moulded (printed parts are weaker across layers); " + _MATWEB),
)}


def material(spec) -> Material:
    """A :class:`Material` from a preset name or a table with ``E``, ``nu``, ``density`` [SI]
    and optionally ``yield`` and ``name``."""
    if isinstance(spec, Material):
        return spec
    if isinstance(spec, str):
        try:
            return PRESETS[spec]
        except KeyError:
            raise SceneError(f"material = {spec!r} is not a preset; use one of "
                             f"{', '.join(repr(k) for k in PRESETS)} or a table with E, nu, "
                             "density (SI) and optionally yield") from None
    if isinstance(spec, dict):
        missing = [k for k in ("E", "nu", "density") if k not in spec]
        if missing:
            raise SceneError(f"material table {spec!r} lacks {', '.join(missing)}: a material "
                             "needs E [Pa], nu and density [kg/m³] (SI), and optionally yield [Pa]")
        extra = set(spec) - {"E", "nu", "density", "yield", "name"}
        if extra:
            raise SceneError(f"material table: unknown key(s) {', '.join(sorted(extra))}; "
                             "allowed: E, nu, density, yield, name")
        return Material(str(spec.get("name", "custom")), spec["E"], spec["nu"], spec["density"],
                        spec.get("yield"), "given in the scene")
    raise SceneError(f"material must be a preset name or a table, got {spec!r}")
