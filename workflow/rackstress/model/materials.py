"""Materials: Young's modulus E, Poisson's ratio ν, density and an optional yield strength.

Values are kept in SI and expressed in a scene's unit system on use
(:meth:`Material.in_units`). The presets are typical room-temperature values for a first look,
each with its source in ``source`` (and in docs); a scene that needs a particular grade gives its
own table.

A table's plain numbers are SI (Pa, kg/m³); a quantity with its unit (``E = "70 GPa"``,
``density = "2.7 g/cm3"``, ``yield = "276 MPa"``) is read by pint and converted, so a table
is unambiguous in any unit system. A table whose numbers no solid has — its wave speed
√(E/ρ), E against its density, its yield against E — is refused, naming the likely slip of
units (:func:`implausible`).

Example
-------
>>> from rackstress.model.units import SYSTEMS
>>> al = material("aluminium")
>>> al.in_units(SYSTEMS["mm-N-s"])["E"], al.nu
(70000.0, 0.33)
>>> material({"E": "70 GPa", "nu": 0.33, "density": "2.7 g/cm3", "yield": "276 MPa"}).E
70000000000.0
"""
from __future__ import annotations

import math
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


#: What no solid does (SI): the wave speed √(E/ρ) from a soft gel's (~1 m/s: E ~1 kPa,
#: ρ ~1000 kg/m³) to diamond's (~17,500 m/s), and the strain at yield σy/E from a
#: single crystal of pure metal's (~1e-5) to 1 (a part that yields at 100 % strain is no solid
#: linear elasticity describes).
WAVE_SPEED = (0.5, 25_000.0)
YIELD_STRAIN = (1e-5, 1.0)
#: The softest engineering solid (a rubber, ~1 MPa): a table of plain numbers softer than that
#: is a slip of units (E in MPa read as Pa: aluminium's 70,000 as 70 kPa) unless its units say
#: otherwise (a gel's ``E = "5 kPa"`` is taken as given).
SOFTEST = 1e6
#: The slips looked for, per field: (factor to SI, the unit the number was likely given in).
SLIPS = {"E": ((1e6, "MPa"), (1e9, "GPa"), (1e3, "kPa")),
         "density": ((1e3, "g/cm³"), (1e12, "t/mm³"), (1e9, "g/mm³")),
         "yield": ((1e6, "MPa"), (1e3, "kPa"))}
_SI_UNIT = {"E": "Pa", "density": "kg/m³", "yield": "Pa"}
_DIMENSION = {"E": "[mass] / [length] / [time] ** 2", "yield": "[mass] / [length] / [time] ** 2",
              "density": "[mass] / [length] ** 3", "nu": "dimensionless"}
_REGISTRY = []


def quantity(key: str, value, where: str = "material"):
    """``value`` in SI: a plain number as it is, a string with its unit (``"70 GPa"``,
    ``"2.7 g/cm3"``) converted by pint; raises :class:`SceneError` naming the field."""
    if not isinstance(value, str):
        return value
    if not _REGISTRY:
        import re

        import pint      # only for a table that has units (its import takes a second)

        # "cm3", "mm2": a power written after the unit, as data sheets do
        _REGISTRY.append(pint.UnitRegistry(preprocessors=[
            lambda t: re.sub(r"(?<=[A-Za-zµ])([23])\b", r"**\1", t)]))
    ureg = _REGISTRY[0]
    import pint

    try:
        q = ureg.Quantity(value.strip())
    except (pint.errors.PintError, ValueError, TypeError, AttributeError) as exc:
        raise SceneError(f"{where}: {key} = {value!r} is not a quantity pint reads ({exc}); "
                         f"write it as a number and a unit, e.g. {_EXAMPLE[key]}") from None
    want = _DIMENSION[key]
    if str(q.dimensionality) != want:
        raise SceneError(f"{where}: {key} = {value!r} is not a "
                         f"{'pressure' if key in ('E', 'yield') else key} "
                         f"(its dimension is {q.dimensionality}); e.g. {_EXAMPLE[key]}")
    si = float(q.to_base_units().magnitude)
    # the conversion's own rounding (2.7 g/cm³ is 2700.0000000000005 kg/m³ in binary) off
    return float(f"{si:.15g}")


_EXAMPLE = {"E": 'E = "70 GPa"', "density": 'density = "2.7 g/cm3"',
            "yield": 'yield = "276 MPa"', "nu": "nu = 0.33"}


def _problems(E: float, rho: float, y, engineering: bool) -> list[str]:
    """What in these SI numbers no solid has (``engineering``: nor an engineering solid)."""
    out = []
    for key, v in (("E", E), ("density", rho)):
        lo, hi, unit, known = RANGE[key]
        if not lo <= v <= hi:
            out.append(f"{key} = {v:g} {unit} is outside what any solid has ({lo:g} to {hi:g} "
                       f"{unit}; {known})")
    if out:
        return out
    c = (E / rho) ** 0.5
    lo, hi = WAVE_SPEED
    if not lo <= c <= hi:
        out.append(f"its wave speed √(E/ρ) = {c:.3g} m/s is {'below' if c < lo else 'above'} "
                   f"any solid's ({lo:g} m/s for a soft gel to {hi:g} for diamond)")
    if engineering and E < SOFTEST:
        out.append(f"E = {E:g} Pa is softer than any rubber (about {SOFTEST:g} Pa)"
                   + (f" at the density of {rho:g} kg/m³" if rho > 1500 else ""))
    if y is not None:
        lo, hi = YIELD_STRAIN
        if not lo <= y / E < hi:
            out.append(f"its yield {y:g} Pa is {y / E:.2g} of E ({'no solid yields that soon' if y / E < lo else 'a strain at yield of 100 % or more'}; "
                       f"metals yield at 1e-4 to 1e-2 of E, polymers up to ~0.05)")
    return out


def implausible(E: float, rho: float, y, given: dict) -> str | None:
    """Why a table's SI numbers are no solid's, with the likely slip of units; None if they
    are a solid's. ``given`` maps each field to True if its unit was written (a quantity):
    such a field is taken as meant, and only the bounds of every solid apply to it."""
    import itertools

    engineering = not given.get("E")
    found = _problems(E, rho, y, engineering)
    if not found:
        return None
    fields = [k for k in ("E", "density", "yield")
              if not given.get(k) and not (k == "yield" and y is None)]
    best = None
    for combo in itertools.product(*[((1.0, None),) + SLIPS[k] for k in fields]):
        changed = {k: f for k, f in zip(fields, combo) if f[1] is not None}
        if not changed:
            continue
        vals = {"E": E, "density": rho, "yield": y}
        for k, (f, _) in changed.items():
            vals[k] = vals[k] * f
        if _problems(vals["E"], vals["density"], vals["yield"], True):
            continue
        # E and yield in one unit first (a table's stresses are written alike: ABS's 2300
        # and 40 both MPa, not E alone in kPa), then the fewest slips, then the wave speed
        # nearest an engineering solid's (~3000 m/s: steel and aluminium 5000, ABS 1500):
        # E = 70 in an aluminium table is GPa, not MPa
        mixed = y is not None and (changed.get("E", (1.0,))[0] != changed.get("yield", (1.0,))[0])
        rank = (mixed, len(changed),
                abs(math.log10((vals["E"] / vals["density"]) ** 0.5 / 3000.0)))
        if best is None or rank < best[2]:
            best = (changed, vals, rank)
    why = "; ".join(found)
    if best is None:
        return (f"these numbers are no solid's: {why}. A table's plain numbers are SI (E and "
                "yield in Pa, density in kg/m³), whatever the scene's units; or give each "
                f"with its unit: {_EXAMPLE['E']}, {_EXAMPLE['density']}, {_EXAMPLE['yield']}")
    orig = {"E": E, "density": rho, "yield": y}
    slips = []
    for k, (f, unit) in best[0].items():
        slips.append(f"{k} = {orig[k]:g} looks like {unit}: {best[1][k]:g} {_SI_UNIT[k]}")
    c = (best[1]["E"] / best[1]["density"]) ** 0.5
    fix = ", ".join(f"{k} = {best[1][k]:g}" for k in best[0]) + " or " + ", ".join(
        f'{k} = "{orig[k]:g} {unit}"' for k, (_, unit) in best[0].items())
    return (f"these numbers are no solid's: {why}. A table's plain numbers are SI (E and yield "
            f"in Pa, density in kg/m³), whatever the scene's units; "
            f"{'; '.join(slips)} (a wave speed of {c:.0f} m/s, a solid's): write {fix}")


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
                             "needs E [Pa], nu and density [kg/m³] (SI, or each with its unit: "
                             "E = \"70 GPa\", density = \"2.7 g/cm3\"), and optionally yield")
        extra = set(spec) - {"E", "nu", "density", "yield", "name"}
        if extra:
            raise SceneError(f"material table: unknown key(s) {', '.join(sorted(extra))}; "
                             "allowed: E, nu, density, yield, name")
        name = str(spec.get("name", "custom"))
        where = f"material '{name}'"
        vals = {k: quantity(k, spec[k], where) for k in ("E", "nu", "density", "yield")
                if k in spec}
        E, rho, y = vals["E"], vals["density"], vals.get("yield")
        if all(isinstance(v, (int, float)) and 0 < v < math.inf for v in (E, rho)) and (
                y is None or (isinstance(y, (int, float)) and 0 < y < math.inf)):
            why = implausible(float(E), float(rho), y,
                              {k: isinstance(spec.get(k), str) for k in ("E", "density", "yield")})
            if why:
                raise SceneError(f"{where}: {why}")
        return Material(name, E, vals["nu"], rho, y, "given in the scene")
    raise SceneError(f"material must be a preset name or a table, got {spec!r}")
