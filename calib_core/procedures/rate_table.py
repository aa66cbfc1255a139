"""The rate-table procedure: one segment per rate plateau -> gyro bias, scale factors,
misalignment, nonlinearity and asymmetry (docs/methods.md 2.4; IEEE Std 952 / 1431 practice).

Settings: `RATE_TABLE.settings` (docs/procedures.md).
"""

from __future__ import annotations

import numpy as np

from calib_core.calibration import Calibration
from calib_core.procedures.base import (
    ATTITUDES,
    ENVIRONMENT,
    EQUIPMENT_PRECHECK,
    RATE_PLATEAUS,
    TABLE_POSITION,
    Procedure,
)
from calib_core.recording import Recording
from calib_core.settings import SettingsIn
from calib_core.solvers.rate_table import SETTINGS, plateau_window, rate_points, solve_rate_table
from calib_core.uncertainty_sources import rate_table_model
from calib_core.units import DEG


def solve_rate_table_procedure(
    segments: dict[str, Recording], gravity: float, settings: SettingsIn = None
) -> Calibration:
    """Rate-table gyro calibration: one segment per rate plateau, labelled "<axis>_<rate>"
    (e.g. "z_+100") with the table feedback in reference["table_rate"] (rad/s).

    settings : typed `SETTINGS` (a mapping is parsed).
    """
    s = SETTINGS.parse(settings)
    points = rate_points(list(segments.values()), **plateau_window(s))
    full = s.full_scale_dps
    given = None
    if s.static_bias_dps is not None:
        std = s.static_bias_std_dps or [0.0, 0.0, 0.0]
        given = (np.asarray(s.static_bias_dps, float) * DEG, np.asarray(std, float) * DEG)
    cal = solve_rate_table(
        points,
        full_scale=None if full is None else float(full) * DEG,
        gyro_bias=s.gyro_bias,
        static_bias=given,
    )
    cal.gravity = gravity
    return cal


RATE_TABLE = Procedure(
    name="rate_table",
    summary="rate plateaus in both directions about each axis: gyro bias, scale factors, "
    "misalignment, nonlinearity and asymmetry",
    segments='one segment per plateau labelled <axis>_<rate in deg/s> ("z_+100", "z_0"), '
    "with the table's feedback as reference channel table_rate (rad/s); [run.settings.sync] "
    "puts the feedback on the IMU clock",
    solver=solve_rate_table_procedure,
    settings=SETTINGS,
    conditions=ENVIRONMENT + ATTITUDES[:1] + RATE_PLATEAUS + (TABLE_POSITION, *EQUIPMENT_PRECHECK),
    reference="docs/methods.md 2.4; IEEE Std 952 / 1431",
    uncertainty=rate_table_model,
    model_checks="chi2 of the rate fit; 0-rate points against the fitted bias; nonlinearity "
    "and asymmetry of each scale factor",
)
