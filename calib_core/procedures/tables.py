"""The tables of ``[run.settings]`` every procedure shares, typed: preprocessing
(calib_core.preprocess.chain: sync, segmentation, outliers, lowpass) and the uncertainty
budget's specifications (pipelines.uncertainty).

Their keys are the chain's own (`SYNC_KEYS`, ...; a test keeps them equal); the steps
check their values again when they run.
"""

from __future__ import annotations

from calib_core.preprocess.chain import SEGMENT_LABELLING
from calib_core.preprocess.outliers import METHODS, POLICIES
from calib_core.preprocess.segments import POSITION_SETTLE_S
from calib_core.procedures.settings import Setting, Settings

_POS = {"low": 0.0, "low_open": True}  # a positive number
_NONNEG = {"low": 0.0}

SYNC = Settings(
    Setting("signal", "text", "", "table_rate", "reference channel of the table's feedback"),
    Setting("signal_kind", "text", "", "rate", "the channel holds a rate (rad/s) or an angle "
            "(rad; differentiated)", choices=("rate", "angle")),
    Setting("imu_axis", "integer", "1", None, "gyro axis along the table axis (0, 1, 2; "
            "absent: the one with the largest variance)", low=0, high=2),
    Setting("max_offset_s", "number", "s", 1.0, "largest clock offset searched", **_POS),
    Setting("max_drift_ppm", "number", "ppm", 200.0, "largest clock drift expected", **_NONNEG),
    Setting("window_s", "number", "s", 30.0, "windows whose local offsets are fitted", **_POS),
    Setting("max_gap_s", "number", "s", None, "a larger spacing in a log is a gap (absent: 5 "
            "sample intervals)", **_POS),
)  # fmt: skip
SEGMENTATION = Settings(
    Setting("window_s", "number", "s", 1.0, "static detector's variance window", **_POS),
    Setting("init_static_s", "number", "s", 10.0, "initial rest the threshold is scaled from",
            **_POS),
    Setting("k", "number", "1", 6.0, "static threshold as a multiple of the initial rest's "
            "variance", **_POS),
    Setting("min_duration_s", "number", "s", 2.0, "shortest rest kept", **_POS),
    Setting("settle_s", "number", "s", POSITION_SETTLE_S, "time dropped at the start of each "
            "rest", **_NONNEG),
    Setting("min_keep_s", "number", "s", 10.0, "shortest part of a rest kept after the settle",
            **_NONNEG),
    Setting("settle_fraction", "number", "1", 0.25, "share of a short rest (under settle_s + "
            "min_keep_s) dropped at each end", low=0.0, high=0.5),
    Setting("min_angle_deg", "number", "deg", 270.0, "smallest turn taken as a rotation", **_POS),
    Setting("labels", "text", "", "faces", "statics by face and axis (x_up, x_ccw) or by sensor "
            "(<sensor>_static, _ccw, _cw)", choices=SEGMENT_LABELLING),
)  # fmt: skip
OUTLIERS = Settings(
    Setting("method", "text", "", "sigma", "detector (none: the step is skipped)",
            choices=(*METHODS, "none")),
    Setting("n_sigma", "number", "1", 3.0, "threshold in standard deviations", **_POS),
    Setting("alpha", "number", "1", 0.05, "significance level (grubbs)", low=0.0, high=1.0,
            low_open=True),
    Setting("window", "integer", "1", None, "samples of the moving window (hampel)", low=1),
    Setting("policy", "text", "", "interpolate", "what happens to a flagged sample",
            choices=POLICIES),
    Setting("channels", "list", "", ["acc", "gyr"], "channels cleaned: acc, gyr"),
)  # fmt: skip
LOWPASS = Settings(
    Setting("cutoff_hz", "number", "Hz", None, "cutoff (or bandwidth_hz with fraction)", **_POS),
    Setting("bandwidth_hz", "number", "Hz", None, "the IMU's bandwidth", **_POS),
    Setting("fraction", "number", "1", 0.25, "cutoff as a share of the bandwidth (the filter "
            "keeps it within 1/5 .. 1/3)", low=0.0, high=1.0, low_open=True),
    Setting("order", "integer", "1", 4, "Butterworth order", low=1),
    Setting("apply_to", "text", "", "static", "the static segments or all",
            choices=("static", "all")),
)  # fmt: skip
UNCERTAINTY = Settings(
    Setting("gravity_expanded_mps2", "number", "m/s^2", None, "expanded uncertainty (k = 2) "
            "of local gravity (absent: by the site's gravity model)", **_NONNEG),
    Setting("cube_angle_deg", "number", "deg", None, "fixture face angle error", **_NONNEG),
    Setting("table_rate_rel", "number", "1", None, "table's relative rate error", **_NONNEG),
    Setting("turn_angle_deg", "number", "deg", None, "turn angle error of a rotation",
            **_NONNEG),
)  # fmt: skip

# table name -> its typed settings
TABLES: dict[str, Settings] = {
    "sync": SYNC,
    "segmentation": SEGMENTATION,
    "outliers": OUTLIERS,
    "lowpass": LOWPASS,
    "uncertainty": UNCERTAINTY,
}
