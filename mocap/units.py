"""Length units of marker data and their conversion to millimetres."""

from __future__ import annotations

from mocap.errors import InputError

__all__ = ["UNITS_TO_MM", "mm_per_unit"]

#: Millimetres per unit, for every unit name found in capture files.
UNITS_TO_MM = {
    "mm": 1.0, "millimeter": 1.0, "millimeters": 1.0, "millimetre": 1.0, "millimetres": 1.0,
    "cm": 10.0, "centimeter": 10.0, "centimeters": 10.0, "centimetre": 10.0, "centimetres": 10.0,
    "m": 1000.0, "meter": 1000.0, "meters": 1000.0, "metre": 1000.0, "metres": 1000.0,
    "in": 25.4, "inch": 25.4, "inches": 25.4,
}


def mm_per_unit(unit: str, *, where: str = "units") -> float:
    """Scale factor from `unit` to millimetres.

    Parameters
    ----------
    unit : str
        A unit name as found in a file (case and surrounding blanks ignored).
    where : str
        What the unit came from, for the error message.

    Raises
    ------
    InputError
        If the unit is not a length unit we know.
    """
    key = str(unit).strip().lower()
    if key not in UNITS_TO_MM:
        raise InputError(f"{where}: unknown length unit {unit!r}; "
                         f"expected one of mm, cm, m, in")
    return UNITS_TO_MM[key]
