"""Pass / warn / fail grades of the figures a QA report shows, with their thresholds.

Every threshold is stated on the page next to its badge: a grade is a reading
aid, the number beside it is the result. The defaults are for facial capture
on a head-sized mesh (markers a few mm apart, errors in mm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Grade", "GRADES", "grade"]


@dataclass(frozen=True)
class Grade:
    """Thresholds of one figure: ``value <= good`` passes, ``<= bad`` warns, else fails.

    Attributes
    ----------
    label : str
        What is graded, with units.
    good, bad : float
        The pass and warn limits (the value grows with the fault).
    why : str
        One sentence on what a failure means.
    """

    label: str
    good: float
    bad: float
    why: str

    def of(self, value) -> str:
        """``"pass"``, ``"warn"``, ``"fail"``, or ``"n/a"`` for a missing value."""
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return "n/a"
        return "pass" if value <= self.good else "warn" if value <= self.bad else "fail"

    def rule(self) -> str:
        """The thresholds as text, e.g. ``"pass ≤ 1, warn ≤ 2, fail > 2"``."""
        return f"pass ≤ {self.good:g}, warn ≤ {self.bad:g}, fail > {self.bad:g}"


#: The graded figures, by key.
GRADES = {
    "rms_mm": Grade("marker RMS error (mm)", 1.0, 2.0,
                    "the basis misses the captured motion by more than a marker's noise"),
    "p95_mm": Grade("95th-percentile marker error (mm)", 2.0, 4.0,
                    "one sample in twenty is off by more than this"),
    "out_of_sample_ratio": Grade("out-of-sample / in-sample RMS", 1.5, 3.0,
                                 "the basis describes the frames it was built from much better "
                                 "than new ones: its in-sample figures flatter it"),
    "binding_rms_mm": Grade("binding RMS distance to the mesh (mm)", 1.0, 3.0,
                            "the markers do not sit where the mesh says the skin is"),
    "head_noise_mm": Grade("head-fit noise (mm)", 0.3, 1.0,
                           "the head markers do not move rigidly: stabilization leaks head "
                           "motion into the face"),
    "head_slips": Grade("head-marker slips", 0.0, 2.0,
                        "a head marker moved on the head during the take"),
}


def grade(key: str, value) -> str:
    """The grade of `value` under :data:`GRADES` [`key`].

    Examples
    --------
    >>> grade("rms_mm", 0.4), grade("rms_mm", 1.5), grade("rms_mm", 9.0)
    ('pass', 'warn', 'fail')
    """
    return GRADES[key].of(value)
