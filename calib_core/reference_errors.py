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
- ``face_angle_error_arcsec[FACE,AXIS]`` (cube, arcsec): the cube face FACE (``+x`` ..
  ``-z``: the face whose outward normal is that axis of the unit as mounted) is not
  square: its normal is rotated by E about the unit's axis AXIS (right-hand rule). Every
  position resting on that face (its normal down: face ``+x`` carries ``x_dn``, face
  ``-x`` carries ``x_up`` and the rotations ``x_ccw``/``x_cw``) had its true specific
  force rotated by E about AXIS; corrected: the segment carries the true reference
  direction in its ``reference_up`` channel (`calib_core.solvers.six_position.
  reference_up`), which the static fits and the integral method's rotation axes read.
- ``temperature_offset_c`` (thermal_chamber, degC): the chamber's reading was the true
  temperature + E; corrected: its ``chamber_temperature`` reference channel minus E here,
  and (pipelines.impact) the run's recorded temperature minus E, which moves the
  lab-condition judgements that read it and the thermal models fitted over the runs. The
  solve itself does not read the chamber's temperature.

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
from calib_core.units import ARCSEC

# quantity -> (equipment kinds, unit, implemented)
QUANTITIES: dict[str, tuple[tuple[str, ...], str, bool]] = {
    "rate_error_ppm": (("rate_table", "centrifuge"), "ppm", True),
    "clock_error_ppm": (("daq",), "ppm", True),
    "radius_error_mm": (("centrifuge",), "mm", True),
    "temperature_offset_c": (("thermal_chamber",), "degC", True),
    "face_angle_error_arcsec": (("cube",), "arcsec", True),
}
_NOT_YET: dict[str, str] = {}  # quantity -> why it is not implemented yet
CHAMBER_CHANNEL = "chamber_temperature"  # the reference channel of the chamber's reading
MAX_OFFSET_C = 50.0  # beyond it the "offset" is a different chamber, not an error
# Position labels a face can carry (statics and rotations of the face procedures).
LABELLED = frozenset(f"{a}_{s}" for a in ("x", "y", "z") for s in ("up", "dn", "ccw", "cw"))
MAX_PPM = 1e5  # 10 %: beyond it the "error" is a different instrument, not a drift
_TEXT = re.compile(r"^\s*([a-z_]+)\s*(?:\[([^\]]*)\])?\s*=\s*([-+0-9.eE]+)\s*$")
FACES = ("+x", "-x", "+y", "-y", "+z", "-z")
MAX_ARCSEC = 3600.0  # 1 deg: beyond it the face is a different fixture, not an error


@dataclass(frozen=True)
class ReferenceError:
    """One error of one piece of reference equipment.

    Attributes
    ----------
    quantity : a key of QUANTITIES.
    value : in the quantity's unit (ppm, mm, degC, arcsec).
    face, about : of a face angle error only: the cube face ("+x" .. "-z", its outward
        normal in the unit's frame) and the unit axis ("x", "y", "z") its normal is
        rotated about; None for the other quantities.
    """

    quantity: str
    value: float
    face: str | None = None
    about: str | None = None

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
        where = f"[{self.face},{self.about}]" if self.face else ""
        return f"{self.quantity}{where}={self.value:g}"


def parse_error(text: str) -> ReferenceError:
    """``QUANTITY=VALUE`` -> ReferenceError; ValueError naming what was expected.

    Quantities not implemented are refused here, with why, never ignored.
    """
    m = _TEXT.match(text or "")
    if not m:
        raise ValueError(
            f"--error: expected QUANTITY=VALUE (e.g. rate_error_ppm=120, "
            f"face_angle_error_arcsec[+x,y]=30), got {text!r}"
        )
    quantity, where, raw = m[1], m[2], m[3]
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
    if unit == "degC" and abs(value) > MAX_OFFSET_C:
        raise ValueError(f"--error: {quantity} = {value:g} degC is beyond +-{MAX_OFFSET_C:g}")
    if quantity == "face_angle_error_arcsec":
        return _face_error(value, where)
    if where is not None:
        raise ValueError(f"--error: {quantity} takes no [..] qualifier, got [{where}]")
    return ReferenceError(quantity, value)


def _face_error(value: float, where: str | None) -> ReferenceError:
    """A face angle error: which face, about which axis (both required)."""
    parts = [p.strip() for p in (where or "").split(",")]
    if where is None or len(parts) != 2:
        raise ValueError(
            "--error: face_angle_error_arcsec needs the face and the axis its normal is "
            "rotated about: face_angle_error_arcsec[FACE,AXIS]=E with FACE one of "
            f"{', '.join(FACES)} and AXIS one of x, y, z (e.g. face_angle_error_arcsec[+x,y]=30)"
        )
    face, about = parts
    if face not in FACES:
        raise ValueError(f"--error: face {face!r}: expected one of {', '.join(FACES)}")
    if about not in ("x", "y", "z"):
        raise ValueError(f"--error: axis {about!r}: expected x, y or z")
    if about == face[1]:
        raise ValueError(
            f"--error: a rotation of face {face} about its own normal {about} does not move "
            "it; the axis is one of the other two"
        )
    if abs(value) > MAX_ARCSEC:
        raise ValueError(
            f"--error: face_angle_error_arcsec = {value:g} arcsec is beyond +-{MAX_ARCSEC:g}"
        )
    return ReferenceError("face_angle_error_arcsec", value, face, about)


def resting_labels(face: str) -> tuple[str, ...]:
    """The segment labels that rest on cube face `face` (its outward normal down).

    Face "+x" down: the unit's x axis points down, x reads -g: "x_dn". Face "-x" down: x
    up, "x_up" and the rotations about x ("x_ccw", "x_cw", made with that axis up).
    """
    axis = face[1]
    return (f"{axis}_dn",) if face[0] == "+" else (f"{axis}_up", f"{axis}_ccw", f"{axis}_cw")


def face_rotation(error: ReferenceError) -> np.ndarray:
    """(3, 3) rotation of the face normal (and of the reference of the positions on it)."""
    from calib_core.attitude import rot_x, rot_y, rot_z

    angle = error.value * ARCSEC
    return {"x": rot_x, "y": rot_y, "z": rot_z}[error.about](angle)


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
    if error.quantity == "face_angle_error_arcsec":
        return _tilted_face(segments, error)
    if error.quantity == "temperature_offset_c":
        return _chamber_offset(segments, error)
    raise ValueError(f"{error.quantity}: not implemented ({_NOT_YET.get(error.quantity, '')})")


def _tilted_face(
    segments: dict[str, Recording], error: ReferenceError
) -> tuple[dict[str, Recording], dict[str, object]]:
    """The positions on the face carry their true up direction (``reference_up``)."""
    from calib_core.solvers.six_position import UP_CHANNEL, nominal_up

    labels = resting_labels(str(error.face))
    if not any(k in LABELLED for k in segments):
        # Automatic segmentation names the positions after this step: which samples rest
        # on the face is not known here, and a guess would be a silently wrong number.
        raise ValueError(
            "face_angle_error_arcsec: the run's segments are cut by automatic segmentation "
            "(no position labels before preprocessing); the face's positions are not known"
        )
    R = face_rotation(error)
    hit = [k for k in segments if k in labels]
    out = dict(segments)
    for k in hit:
        rec = segments[k]
        up = R @ nominal_up(k)
        out[k] = replace(rec, reference={**rec.reference, UP_CHANNEL: np.tile(up, (len(rec), 1))})
    what = (
        f"reference direction of {', '.join(hit)} rotated by {error.value:g} arcsec about "
        f"{error.about} (face {error.face})"
        if hit
        else f"no segment rests on face {error.face} ({', '.join(labels)})"
    )
    return out, {"affected": bool(hit), "what": what, "factor": 1.0}


def _chamber_offset(
    segments: dict[str, Recording], error: ReferenceError
) -> tuple[dict[str, Recording], dict[str, object]]:
    """The chamber's temperature channel as it truly was (reading - E)."""
    hit = [k for k, r in segments.items() if CHAMBER_CHANNEL in r.reference]
    out = dict(segments)
    for k in hit:
        rec = segments[k]
        shifted = np.asarray(rec.reference[CHAMBER_CHANNEL], dtype=float) - error.value
        out[k] = replace(rec, reference={**rec.reference, CHAMBER_CHANNEL: shifted})
    what = f"chamber temperature - {error.value:g} degC" + (
        f"; reference channel {CHAMBER_CHANNEL} in {len(hit)} segments" if hit else ""
    )
    # The run's recorded temperature is corrected with the manifest (pipelines.impact).
    return out, {"affected": True, "what": what, "factor": 1.0}


def _scaled_rate(rec: Recording, factor: float) -> Recording:
    ref = dict(rec.reference)
    ref["table_rate"] = np.asarray(ref["table_rate"], dtype=float) * factor
    return replace(rec, reference=ref)
