"""`calib export RUN`: one archived calibration in the format a lab or an autopilot reads.

The formats (docs/exports.md): ``json`` (the archive's canonical document),
``px4`` (QGroundControl .params), ``ardupilot`` (Mission Planner .param), ``csv``
(one row per parameter), ``mat`` (MATLAB v5), and from a static-bias (Allan) run the
noise models ``kalibr`` (imu.yaml) and ``openvins`` (kalibr_imu_chain.yaml). The
unit's current thermal model is added when it has one (``thermal=False`` leaves it
out). What a format cannot carry is returned as warnings and written into the file's
comment header, never left out silently. The writers are in `pipelines.exports` and
`pipelines.nav_exports`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from calib_core.calibration import Calibration
from calib_core.nav_noise import nav_noise
from calib_core.thermal import ThermalModel
from pipelines import autopilot, exports, nav_exports
from storage import queries
from storage.db import Archive

FORMATS = ("json", "px4", "ardupilot", "csv", "mat", "kalibr", "openvins")
NOISE_FORMATS = ("kalibr", "openvins")  # noise models: static-bias runs only
SUFFIX = {
    "json": ".json",
    "px4": ".params",
    "ardupilot": ".param",
    "csv": ".csv",
    "mat": ".mat",
    "kalibr": "_imu.yaml",
    "openvins": "_kalibr_imu_chain.yaml",
}
MEDIA_TYPE = {
    "json": "application/json",
    "px4": "text/plain; charset=us-ascii",
    "ardupilot": "text/plain; charset=us-ascii",
    "csv": "text/csv; charset=utf-8",
    "mat": "application/x-matlab-data",
    "kalibr": "application/yaml",
    "openvins": "application/yaml",
}


@dataclass
class Export:
    """One export: the file's bytes, its suggested name and media type, the warnings."""

    data: bytes
    filename: str
    media_type: str
    warnings: list[str] = field(default_factory=list)


def _thermal(archive: Archive, serial: str) -> tuple[ThermalModel | None, int | None]:
    tm = queries.latest_thermal_model(archive, serial, None)
    return (None, None) if tm is None else (ThermalModel.from_dict(tm["document"]), tm["id"])


def export_run(
    archive: Archive,
    run_id: str,
    fmt: str,
    *,
    revision: int | None = None,
    thermal: bool = True,
    instance: int | None = None,
    accel_id: int | None = None,
    gyro_id: int | None = None,
    rostopic: str = nav_exports.DEFAULT_ROSTOPIC,
    update_rate_hz: float | None = None,
    rotation: str | None = None,
    vehicle_id: int = 1,
) -> Export:
    """Export the calibration of run `run_id` (current revision unless `revision`).

    Parameters
    ----------
    archive : the archive (`storage.db.Archive`).
    run_id : the full run id.
    fmt : one of FORMATS.
    revision : calibration revision, None for the current one.
    thermal : add the unit's current thermal model (px4, ardupilot, csv, mat).
    instance : PX4 sensor instance (default 0) / ArduPilot IMU number (default: the
        DataFlash log's IMU instance + 1, else 1).
    accel_id, gyro_id : PX4 device ids (CAL_ACC<i>_ID, CAL_GYRO<i>_ID, TC_*_ID); None: the
        ids the run's ULog recorded, else the export is refused (`pipelines.autopilot`).
    rotation : the firmware's rotation of the calibrated axes (PX4 SENS_BOARD_ROT /
        ArduPilot AHRS_ORIENTATION names), None for none.
    vehicle_id : the PX4 file's vehicle (MAVLink system) id.
    rostopic : the IMU topic written into kalibr / openvins files.
    update_rate_hz : kalibr / openvins update_rate, Hz (None: the run's sample rate).

    Returns
    -------
    Export. Raises ValueError for an unknown format, a value outside the
    firmware's range or a noise model asked of a run that is not a static-bias run,
    LookupError for an unknown run or revision.
    """
    if fmt not in FORMATS:
        raise ValueError(f"unknown export format {fmt!r}; expected one of {', '.join(FORMATS)}")
    doc = queries.export_calibration(archive, run_id, revision)
    name = f"{doc['unit']['serial']}_{run_id}_rev{doc['revision']}{SUFFIX[fmt]}"
    if fmt == "json":
        text = json.dumps(doc, indent=2, default=str) + "\n"
        return Export(text.encode(), name, MEDIA_TYPE[fmt])
    cal = Calibration.from_dict(doc["calibration"])
    if fmt in NOISE_FORMATS:
        text = _noise_model(fmt, cal, doc, rostopic, update_rate_hz)
        return Export(text.encode("ascii", "backslashreplace"), name, MEDIA_TYPE[fmt])
    model, model_id = _thermal(archive, doc["unit"]["serial"]) if thermal else (None, None)
    summary = queries.run_summary(archive, run_id)
    cal_temp = summary.temperature_c
    src = _Source(doc, cal, model, model_id, None if cal_temp is None else float(cal_temp))
    if fmt not in autopilot.FIRMWARES:
        data, notes = _encode(fmt, src)
        return Export(data, name, MEDIA_TYPE[fmt], notes)
    target = _Target(
        autopilot.rotation(rotation, fmt),
        autopilot.recorded_devices(summary.calibration.step_statistics("ingest")),
        instance,
        accel_id,
        gyro_id,
        vehicle_id,
    )
    data, notes = _firmware(fmt, src, target)
    return Export(data, name, MEDIA_TYPE[fmt], notes)


@dataclass(frozen=True)
class _Source:
    """What a parameter file is written from: the export document, its calibration, the
    unit's thermal model (and its id) and the run's temperature (deg C)."""

    doc: dict[str, Any]
    cal: Calibration
    model: ThermalModel | None
    model_id: int | None
    cal_temp: float | None


@dataclass(frozen=True)
class _Target:
    """Where an autopilot file goes: the mounting, the ids the log recorded and the options."""

    rot: autopilot.Rotation
    recorded: dict[str, int]
    instance: int | None
    accel_id: int | None
    gyro_id: int | None
    vehicle_id: int


def _header(
    doc: dict[str, Any],
    model_id: int | None,
    notes: list[str],
    more: tuple[str, ...] | list[str] = (),
) -> str:
    unit = doc["unit"]
    lines = [
        f"imu-calib export of {unit['serial']} ({unit['model']}), run {doc['run']['run_id']} "
        f"revision {doc['revision']}, verdict {doc['verdict']}, software {doc['software_version']}",
        "thermal model: " + ("none" if model_id is None else f"id {model_id}"),
        *more,
    ]
    return "\n".join(lines + [f"WARNING: {n}" for n in notes])


def _noise_model(
    fmt: str, cal: Calibration, doc: dict[str, Any], rostopic: str, update_rate_hz: float | None
) -> str:
    """The kalibr / openvins file of a static-bias run (pipelines.nav_exports)."""
    run = doc["run"]
    try:  # what the run's solver left in info decides, not the procedure's name
        nav = nav_noise(cal.info)
    except ValueError as exc:
        raise ValueError(
            f"--format {fmt}: run {run['run_id']} is a {cal.procedure!r} run; {exc}"
        ) from None
    rate = nav.sample_rate_hz if update_rate_hz is None else float(update_rate_hz)
    header = _header(doc, None, [f"run warning: {w}" for w in cal.warnings])
    header = header.replace("\nthermal model: none", "")  # a noise model has no thermal part
    write = nav_exports.kalibr_yaml if fmt == "kalibr" else nav_exports.openvins_yaml
    return write(nav, update_rate_hz=rate, rostopic=rostopic, header=header)


def _firmware(fmt: str, src: _Source, target: _Target) -> tuple[bytes, list[str]]:
    """The PX4 or ArduPilot file's bytes and its warnings."""
    doc, cal, model, cal_temp, model_id = src.doc, src.cal, src.model, src.cal_temp, src.model_id
    rng = None if model is None else (model.t_min, model.t_max)
    common = {"unit": doc["unit"]["serial"], "run": doc["run"]["run_id"], "model_range": rng}
    applied = {"model": model, "cal_temp": cal_temp, "rot": target.rot}  # by either exporter
    if fmt == "px4":
        acc_id, gyr_id, said = autopilot.px4_device_ids(
            target.recorded, target.accel_id, target.gyro_id
        )
        instance = 0 if target.instance is None else target.instance
        rows, notes = exports.px4_calibration_parameters(
            cal, instance=instance, accel_id=acc_id, gyro_id=gyr_id, **applied
        )
        settings = [
            f"sets CAL_ACC{instance}_* / CAL_GYRO{instance}_*"
            + (f" and TC_A{instance}_* / TC_G{instance}_*" if model is not None else "")
            + f" of the sensors with device ids {acc_id} (accelerometer) and {gyr_id} (gyro), "
            f"{said}; the vehicle's SENS_BOARD_ROT stays as it is"
        ]
        head = autopilot.header_lines("px4", rot=target.rot, settings=settings, **common)
        text = exports.px4_params_text(
            rows, header=_header(doc, model_id, notes, head), vehicle_id=target.vehicle_id
        )
        return text.encode("ascii", "backslashreplace"), notes
    imu = target.instance
    if imu is None:
        imu = target.recorded["imu"] + 1 if "imu" in target.recorded else 1
    rows, notes = exports.ardupilot_calibration_parameters(cal, imu=imu, **applied)
    settings = [
        f"sets IMU {imu} (the log's instance {imu - 1}): its offsets and scales"
        + (f", INS_TCAL{imu}_*" if model is not None else "")
        + "; the vehicle's AHRS_ORIENTATION stays as it is"
    ]
    head = autopilot.header_lines("ardupilot", rot=target.rot, settings=settings, **common)
    text = exports.ardupilot_params_text(rows, header=_header(doc, model_id, notes, head))
    return text.encode("ascii", "backslashreplace"), notes


def _encode(fmt: str, src: _Source) -> tuple[bytes, list[str]]:
    """The file's bytes and the warnings of the csv and mat formats."""
    doc, cal, model, cal_temp, model_id = src.doc, src.cal, src.model, src.cal_temp, src.model_id
    if fmt == "csv":
        return exports.csv_text(exports.parameter_rows(cal, model)).encode(), []
    meta = {
        "serial": doc["unit"]["serial"],
        "model": doc["unit"]["model"],
        "run_id": doc["run"]["run_id"],
        "started_at": doc["run"]["started_at"],
        "revision": doc["revision"],
        "verdict": doc["verdict"],
        "software_version": doc["software_version"],
        "calibration_temperature_c": float("nan") if cal_temp is None else cal_temp,
        "thermal_model_id": 0 if model_id is None else model_id,
    }
    return exports.mat_bytes(exports.mat_variables(cal, meta, model)), []
