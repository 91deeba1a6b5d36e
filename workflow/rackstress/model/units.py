"""Unit systems a scene can declare: the paper's dimensionless units, mm–N–s–MPa and SI.

The engines work in accelerations (the paper's operators, Eqs. 8–14) and never see a unit; a
unit system says what the scene's numbers mean, so that materials (given in SI) and physical
loads can be turned into the operators' coefficients, and stresses can be reported in the
system's stress unit. Every system here is *consistent*: force = mass · length / time², stress =
force / length², density = mass / length³, so no conversion factor appears inside the model.

Example
-------
>>> u = SYSTEMS["mm-N-s"]
>>> u.stress, round(u.from_si("stress", 70e9), 6), u.from_si("density", 2700.0)
('MPa', 70000.0, 2.7e-09)
"""
from __future__ import annotations

from dataclasses import dataclass

from rackstress.errors import SceneError


@dataclass(frozen=True)
class Units:
    """A consistent unit system: each quantity's name and its size in SI units."""

    name: str
    length: str
    time: str
    mass: str
    force: str
    stress: str
    density: str
    #: size of one unit of each quantity in SI (length in m, mass in kg, time in s, ...)
    si: dict

    @property
    def physical(self) -> bool:
        """False for the paper's dimensionless units (no material, no newtons)."""
        return bool(self.si)

    def from_si(self, quantity: str, value: float) -> float:
        """``value`` given in SI, expressed in this system's unit of ``quantity``."""
        if not self.physical:
            raise SceneError(f"the scene's units are '{self.name}' (dimensionless): a {quantity} "
                             "in SI cannot be used; declare units = \"mm-N-s\" or \"SI\"")
        return float(value) / self.si[quantity]


def _si(length: float, mass: float, time: float) -> dict:
    force = mass * length / time ** 2
    return {"length": length, "mass": mass, "time": time, "force": force,
            "stress": force / length ** 2, "density": mass / length ** 3}


#: The unit systems by the name a scene file gives (``units = "mm-N-s"``).
SYSTEMS = {
    "paper": Units("paper", "unit", "unit", "unit", "unit", "unit", "unit", {}),
    # tonne (1000 kg), mm, s: force N, stress MPa, density t/mm³ (steel 7.85e-9)
    "mm-N-s": Units("mm-N-s", "mm", "s", "t", "N", "MPa", "t/mm³", _si(1e-3, 1e3, 1.0)),
    "SI": Units("SI", "m", "s", "kg", "N", "Pa", "kg/m³", _si(1.0, 1.0, 1.0)),
}
PAPER = SYSTEMS["paper"]


def units(name: str) -> Units:
    """The unit system called ``name``; an unknown name is a :class:`SceneError`."""
    try:
        return SYSTEMS[name]
    except KeyError:
        raise SceneError(f"units = {name!r} is not a unit system rackstress knows; use one of "
                         f"{', '.join(repr(k) for k in SYSTEMS)}") from None
