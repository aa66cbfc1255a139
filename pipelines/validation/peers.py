"""Method validation, the peers: imucal (Ferraris / turntable six-position) and allantools
(overlapping Allan deviation) run on a run's raw samples, their results in our conventions.

Each peer is imported when it runs, never by calib_core or at start: a peer not installed
answers "not installed" with the extra to install (`pip install 'imu-calib[validate]'`).
The conversions (docs/methods.md, "Peer conventions"):

- imucal reads ``raw = K R a + b`` (K diagonal, R with unit rows) and, for the gyro,
  ``raw = K_g R_g w + K_ga a + b_g``; fed our samples in m/s^2 and deg/s, ``K R`` is our
  ``I + M`` (scale = diagonal - 1, misalignment = off-diagonal), ``K_ga`` our g-sensitivity
  in (deg/s)/(m/s^2) and ``b_g`` our gyro bias in deg/s, both converted to rad/s.
- imucal takes one turn per axis of a signed angle (-360 deg x turns: clockwise); a run
  with both senses gives it the clockwise turns, one with counter-clockwise turns only
  +360 deg x turns. It integrates sum(w) / f_s: f_s is the record's median rate.
- allantools' oadev takes rate ("freq") data at the record's sample rate and our cluster
  times; its deviation goes through our noise-term reading (calib_core.noise), so the
  comparison is of the Allan deviation and of the terms read from it.
"""

from __future__ import annotations

import importlib.metadata

import numpy as np

from calib_core import params
from calib_core.recording import Recording
from calib_core.units import DEG

STATICS = ("x_up", "x_dn", "y_up", "y_dn", "z_up", "z_dn")
IMUCAL_SECTIONS = {
    "x_up": "x_p",
    "x_dn": "x_a",
    "y_up": "y_p",
    "y_dn": "y_a",
    "z_up": "z_p",
    "z_dn": "z_a",
}


class PeerCannotTreatError(ValueError):
    """The peer cannot treat this run (the reason says why)."""


def installed_version(peer: str) -> str | None:
    """The peer's installed version, None when it is not installed."""
    try:
        return importlib.metadata.version(peer)
    except importlib.metadata.PackageNotFoundError:
        return None


def rate_of(rec: Recording) -> float:
    """A record's sample rate, Hz: 1 / its median time step."""
    return float(1.0 / np.median(np.diff(rec.t)))


def _turns(segments: dict[str, Recording]) -> tuple[str, float]:
    """The rotation sense given to imucal and its sign: "cw" (-1) where every axis has a
    clockwise turn, else "ccw" (+1) where every axis has a counter-clockwise one."""
    for sense, sign in (("cw", -1.0), ("ccw", 1.0)):
        if all(f"{a}_{sense}" in segments for a in params.AXES):
            return sense, sign
    raise PeerCannotTreatError(
        "imucal's Ferraris procedure needs one turn about each of x, y, z in one sense; "
        f"this run has {sorted(k for k in segments if k.endswith(('_cw', '_ccw'))) or 'none'}"
    )


def imucal_parameters(
    segments: dict[str, Recording], gravity: float, turns: int, turntable: bool
) -> dict[str, float]:
    """imucal's solution of a six-position + rotations run in our canonical names (SI).

    Parameters
    ----------
    segments : label -> Recording as read from the raw bytes (x_up .. z_dn, x_cw / x_ccw ...).
    gravity : the run's gravity, m/s^2 (imucal's ``grav``).
    turns : whole turns per rotation.
    turntable : TurntableCalibration (a rate table turned the unit) rather than
        FerrarisCalibration (by hand); the arithmetic is the same.

    Raises
    ------
    PeerCannotTreatError when a face or a turn is missing.
    """
    from imucal import FerrarisCalibration, TurntableCalibration
    from imucal.ferraris_calibration import FerrarisSignalRegions

    missing = [s for s in STATICS if s not in segments]
    if missing:
        lacks = ", ".join(missing)
        raise PeerCannotTreatError(f"imucal needs the six faces; this run lacks {lacks}")
    sense, sign = _turns(segments)
    regions: dict[str, np.ndarray] = {}
    for label in STATICS:
        rec = segments[label]
        regions[f"acc_{IMUCAL_SECTIONS[label]}"] = rec.acc
        regions[f"gyr_{IMUCAL_SECTIONS[label]}"] = rec.gyr / DEG
    rates = []
    for a in params.AXES:
        rec = segments[f"{a}_{sense}"]
        regions[f"acc_{a}_rot"] = rec.acc
        regions[f"gyr_{a}_rot"] = rec.gyr / DEG
        rates.append(rate_of(rec))
    kind = TurntableCalibration if turntable else FerrarisCalibration
    cal = kind(grav=gravity, expected_angle=sign * 360.0 * turns).compute(
        FerrarisSignalRegions(**regions), float(np.median(rates)), "m/s^2", "deg/s"
    )
    out: dict[str, float] = {}
    acc = np.asarray(cal.K_a) @ np.asarray(cal.R_a)
    gyr = np.asarray(cal.K_g) @ np.asarray(cal.R_g)
    for sensor, matrix, bias, unit in (
        ("acc", acc, np.asarray(cal.b_a), 1.0),
        ("gyr", gyr, np.asarray(cal.b_g), DEG),
    ):
        for i, row in enumerate(params.matrix_names(sensor)):
            out[params.bias(sensor, params.AXES[i])] = float(bias[i] * unit)
            for j, name in enumerate(row):
                out[name] = float(matrix[i, j] - (1.0 if i == j else 0.0))
    gsens = np.asarray(cal.K_ga) * DEG
    for i, row in enumerate(params.gsens_names()):
        for j, name in enumerate(row):
            out[name] = float(gsens[i, j])
    return out


def imucal_turn_uncertainty(
    segments: dict[str, Recording], gravity: float, turns: int
) -> dict[str, float]:
    """Standard uncertainties of imucal's gyro scale and misalignment: imucal states none,
    and its estimate is the paper's literal one (each channel integrated over the whole
    record of the turns in one sense, `_turns`), whose Type A our solver states for the
    same samples (six_position_integral, turn_estimator "whole_record", one sense). Left
    out, E_n would take ours alone, and the more precise ours the more imucal's own noise
    would read as disagreement.

    Returns
    -------
    canonical name -> standard uncertainty (gyr.scale.*, gyr.misalign.*).
    """
    from calib_core.procedures import solve

    sense, _ = _turns(segments)
    used = {k: v for k, v in segments.items() if k in STATICS or k.endswith(f"_{sense}")}
    settings = {"turn_estimator": "whole_record", "rotation_directions": "any", "turns": turns}
    cal = solve("six_position_integral", used, gravity, settings)
    names = [n for row in params.matrix_names("gyr") for n in row]
    return {n: cal.parameters[n].std for n in names}


def allantools_curves(rate: np.ndarray, rate_hz: float, taus: np.ndarray) -> np.ndarray:
    """allantools' overlapping Allan deviation of each channel of `rate` (N, C) at `taus`.

    Returns (K, C), the unit of `rate`. Raises PeerCannotTreatError when allantools returns
    other cluster times than ours (it rounds tau to whole samples as we do).
    """
    import allantools

    out = np.empty((len(taus), rate.shape[1]))
    for c in range(rate.shape[1]):
        t2, ad, _, _ = allantools.oadev(rate[:, c], rate=rate_hz, data_type="freq", taus=taus)
        if len(t2) != len(taus) or not np.allclose(t2, taus, rtol=1e-9):
            raise PeerCannotTreatError(
                f"allantools returned {len(t2)} cluster times for our {len(taus)}; "
                "the curves cannot be compared point by point"
            )
        out[:, c] = ad
    return out
