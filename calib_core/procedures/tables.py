"""The tables of ``[run.settings]`` every procedure shares, typed: preprocessing (declared
with its steps, calib_core.preprocess.chain: sync, segmentation, outliers, lowpass) and the
uncertainty budget's specifications (pipelines.uncertainty)."""

from __future__ import annotations

from calib_core.preprocess.chain import PREPROCESSING
from calib_core.settings import Setting, Settings

UNCERTAINTY = Settings(
    Setting("gravity_expanded_mps2", "number", "m/s^2", None, "expanded uncertainty (k = 2) "
            "of local gravity (absent: by the site's gravity model)", low=0.0),
    Setting("cube_angle_deg", "number", "deg", None, "fixture face angle error", low=0.0),
    Setting("table_rate_rel", "number", "1", None, "table's relative rate error", low=0.0),
    Setting("turn_angle_deg", "number", "deg", None, "turn angle error of a rotation",
            low=0.0),
)  # fmt: skip

# table name -> its typed settings
TABLES: dict[str, Settings] = {**PREPROCESSING, "uncertainty": UNCERTAINTY}
