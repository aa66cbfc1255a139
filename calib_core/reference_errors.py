"""Errors of reference equipment found after the fact, the science: what each one does to a
run's reference, and the run's recordings with the reference corrected (`calib impact`,
ISO/IEC 17025 clause 7.10; docs/impact.md).

Each quantity belongs to one kind of equipment and enters the solve where the equipment
does:

- ``rate_error_ppm`` (rate_table or centrifuge, ppm): the table's rate reading was
  (1 + E) x the true rate; corrected: ``reference["table_rate"] /= 1 + E``.
- ``clock_error_ppm`` (daq, ppm): the DAQ clock ran fast, its time stamps were (1 + E) x
  true time; corrected: ``t /= 1 + E`` in every segment.
- ``radius_error_mm`` (centrifuge, mm): the arm's nominal radius was off by E. The
  centrifuge procedure estimates the effective radius from its near-1 g run
  (`calib_core.solvers.centrifuge_model.effective_radius`), so no solve reads the nominal
  radius: every run is reported as not affected, with that reason.
- ``temperature_offset_c`` (thermal_chamber, degC), ``face_angle_error_arcsec`` (cube,
  arcsec): named, refused as not implemented (why: `parse_error`'s message).

A rate-table rate error reaches only the solves that read the table's rate (procedure
rate_table, the centrifuge's table rate); the integral method takes angles from turns and
is not changed by it. A DAQ clock error reaches every integral over time (the integral
method's angles, the Allan cluster times); a plateau mean is not changed by it. A run the
error does not reach is reported as such, its solve is not repeated for nothing.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np

from calib_core.recording import Recording

# quantity -> (equipment kinds, unit, implemented)
QUANTITIES: dict[str, tuple[tuple[str, ...], str, bool]] = {
    "rate_error_ppm": (("rate_table", "centrifuge"), "ppm", True),
    "clock_error_ppm": (("daq",), "ppm", True),
    "radius_error_mm": (("centrifuge",), "mm", True),
    "temperature_offset_c": (("thermal_chamber",), "degC", False),
    "face_angle_error_arcsec": (("cube",), "arcsec", False),
}
_NOT_YET = {
    "temperature_offset_c": "a chamber's offset changes the temperatures of a thermal campaign; "
    "refit it (calib thermal fit) with the corrected temperatures",
    "face_angle_error_arcsec": "a face angle tilts one position's reference attitude; which "
    "face and axis is not part of a single number",
}
MAX_PPM = 1e5  # 10 %: beyond it the "error" is a different instrument, not a drift
_TEXT = re.compile(r"^\s*([a-z_]+)\s*=\s*([-+0-9.eE]+)\s*$")


@dataclass(frozen=True)
class ReferenceError:
    """One error of one piece of reference equipment.

    Attributes
    ----------
    quantity : a key of QUANTITIES.
    value : in the quantity's unit (ppm, mm, degC, arcsec).
    """

    quantity: str
    value: float

    @property
    def kinds(self) -> tuple[str, ...]:
        """The equipment kinds this error can belong to."""
        return QUANTITIES[self.quantity][0]

    @property
    def kind(self) -> str:
        return " or ".join(self.kinds)

    @property
    def unit(self) -> str:
        return QUANTITIES[self.quantity][1]

    def __str__(self) -> str:
        return f"{self.quantity}={self.value:g}"


def parse_error(text: str) -> ReferenceError:
    """``QUANTITY=VALUE`` -> ReferenceError; ValueError naming what was expected.

    Quantities not implemented are refused here, with why, never ignored.
    """
    m = _TEXT.match(text or "")
    if not m:
        raise ValueError(
            f"--error: expected QUANTITY=VALUE (e.g. rate_error_ppm=120), got {text!r}"
        )
    quantity, raw = m[1], m[2]
    if quantity not in QUANTITIES:
        raise ValueError(f"--error: unknown quantity {quantity!r}; known: {', '.join(QUANTITIES)}")
    try:
        value = float(raw)
    except ValueError:
        raise ValueError(f"--error: {quantity}: expected a number, got {raw!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"--error: {quantity}: expected a finite number, got {raw!r}")
    kinds, unit, implemented = QUANTITIES[quantity]
    if not implemented:
        raise ValueError(
            f"--error: {quantity} ({', '.join(kinds)}) is not implemented: {_NOT_YET[quantity]}"
        )
    if unit == "ppm" and abs(value) > MAX_PPM:
        raise ValueError(f"--error: {quantity} = {value:g} ppm is beyond +-{MAX_PPM:g} ppm")
    return ReferenceError(quantity, value)


def correct_segments(
    segments: dict[str, Recording], error: ReferenceError
) -> tuple[dict[str, Recording], dict[str, object]]:
    """The segments with the reference as it truly was, and what was changed.

    Returns
    -------
    (segments, statistics): statistics has ``affected`` (bool), ``what`` (words) and
    ``factor`` (the multiplier applied); unaffected segments are the same objects.
    """
    factor = 1.0 / (1.0 + error.value * 1e-6)
    if error.quantity == "rate_error_ppm":
        hit = [k for k, r in segments.items() if "table_rate" in r.reference]
        out = {k: (_scaled_rate(r, factor) if k in hit else r) for k, r in segments.items()}
        what = (
            f"reference table_rate x {factor:.12g} in {len(hit)} of {len(segments)} segments"
            if hit
            else "no segment has a table_rate reference: the table's rate does not "
            "enter this run's solve"
        )
        return out, {"affected": bool(hit), "what": what, "factor": factor}
    if error.quantity == "clock_error_ppm":
        out = {k: replace(r, t=np.asarray(r.t, dtype=float) * factor) for k, r in segments.items()}
        what = f"time stamps x {factor:.12g} in all {len(segments)} segments"
        return out, {"affected": True, "what": what, "factor": factor}
    if error.quantity == "radius_error_mm":
        what = (
            "the centrifuge procedure estimates the effective radius from its near-1 g "
            "run; the arm's nominal radius enters no solve"
        )
        return dict(segments), {"affected": False, "what": what, "factor": 1.0}
    raise ValueError(f"{error.quantity}: not implemented ({_NOT_YET.get(error.quantity, '')})")


def _scaled_rate(rec: Recording, factor: float) -> Recording:
    ref = dict(rec.reference)
    ref["table_rate"] = np.asarray(ref["table_rate"], dtype=float) * factor
    return replace(rec, reference=ref)
