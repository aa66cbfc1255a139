"""Thermal compensation, the CLI: `calib thermal fit|show|export`, `apply`, `trend`, `fleet`.

The glue behind them: pipelines.thermal_campaign, pipelines.apply, pipelines.trends.

Tables go to stdout (or JSON with --json), messages to stderr. Exit codes: 0
done, 2 invalid input or nothing to work on.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from pipelines.cli_shared import (
    ArchiveOpt,
    AtOpt,
    DeviceIdOpt,
    JsonOpt,
    RotationOpt,
    VehicleIdOpt,
    app,
    at_instant,
    err,
    fail,
    fail_on,
    frame_records,
    open_archive,
    print_facts,
    print_frame,
    print_json,
    print_table,
    sub_app,
    warn,
)

thermal_app = sub_app("Temperature compensation: fit, show and export.")
app.add_typer(thermal_app, name="thermal")

PlotOpt = Annotated[Path | None, typer.Option("--plot", help="Also draw the plot into this PNG.")]


def _run(fn, *args, **kwargs) -> Any:  # noqa: ANN001 - any pipeline function
    from pipelines.ingest import IngestError

    with fail_on(ValueError, LookupError, IngestError, OSError):
        return fn(*args, **kwargs)


@thermal_app.command("fit")
def thermal_fit(
    serial: str,
    runs: Annotated[
        list[str] | None, typer.Option("--runs", help="Run ids of the campaign (default: all).")
    ] = None,
    max_order: Annotated[int, typer.Option(help="Highest polynomial order tried.")] = 3,
    alpha: Annotated[float, typer.Option(help="Significance level of the order test.")] = 0.01,
    t_ref: Annotated[float | None, typer.Option(help="Reference temperature, deg C.")] = None,
    archive: ArchiveOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Fit and archive the thermal model of SERIAL from its runs at several temperatures."""
    from sqlalchemy.exc import SQLAlchemyError

    from pipelines.thermal_campaign import thermal_fit as fit

    run_ids = [r for item in runs or [] for r in item.split(",") if r]
    settings = {"max_order": max_order, "alpha": alpha, "t_ref": t_ref}
    arch = open_archive(archive)
    try:
        summary = _run(fit, arch, serial, run_ids or None, settings)
    except SQLAlchemyError as exc:  # the write failed: no model was archived
        from storage.write_failures import describe

        fail(f"thermal model of {serial} not written: {describe(exc, arch.url) or exc}")
    if as_json:
        print_json(summary)
        return
    import pandas as pd

    from pipelines.reports.display import quantity, shown

    rows = [  # SI in the summary (--json), the display unit here, as `calib show` prints
        {
            "parameter": n,
            "order": summary["orders"][n],
            "unit": shown(n, 0.0).unit,
            "rms before": quantity(n, b["rms_before"], 3),
            "rms after": quantity(n, b["rms_after"], 3),
            "rms held out": quantity(n, b["rms_holdout"], 3),
            "hysteresis": _hyst(n, summary["hysteresis"].get(n)),
        }
        for n, b in summary["benefit"].items()
    ]
    print_frame(
        pd.DataFrame(rows),
        f"Thermal model {summary['model_id']} of {serial}: {summary['t_min']:g} .. "
        f"{summary['t_max']:g} deg C, T_ref {summary['t_ref']:g}, {len(summary['runs'])} runs",
    )


def _hyst(name: str, h: dict | None) -> str:
    """A curve's hysteresis (SI in) in `name`'s display unit, "-" without one."""
    from pipelines.reports.display import U_DIGITS, quantity

    if h is None:
        return "-"
    said = f"{quantity(name, h['value'], 3)} ± {quantity(name, h['std'], U_DIGITS)}"
    return said + (" DETECTED" if h["detected"] else "")


@thermal_app.command("show")
def thermal_show(
    serial: str,
    at: AtOpt = None,
    archive: ArchiveOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """The archived thermal model of SERIAL: range, reference, each parameter's curve."""
    from storage import queries

    model = _run(queries.latest_thermal_model, open_archive(archive), serial, at_instant(at))
    if model is None:
        fail(
            f"{serial} has no thermal model"
            + (f" as of {at}" if at else "")
            + f": run `calib thermal fit {serial}` first"
        )
    if as_json:
        print_json(model)
        return
    doc = model["document"]
    print_facts(
        {
            "unit": serial,
            "model": f"{model['id']} ({model['model_name']} v{model['model_version']}, "
            f"software {doc.get('software_version', '-')})",
            "created": model["created_at"],
            "range": f"{model['t_min']:g} .. {model['t_max']:g} deg C",
            "reference temperature": f"{model['t_ref']:g} deg C",
            "fitted to the runs": ", ".join(
                r["run_id"] + ("" if r["revision"] == 1 else f" (revision {r['revision']})")
                for r in model["runs"]
            ),
            "superseded by": model["superseded_by"] or "not superseded",
        },
        f"Thermal model of {serial}",
    )
    print_table(
        f"Curves: value(T) = c0 + c1 (T - {model['t_ref']:g}) + ..., c_k per deg C^k "
        "(display units; --json: SI)",
        [
            "parameter",
            "order",
            "coefficients c0, c1, ...",
            "residual sigma",
            "points",
            "hysteresis",
        ],
        [_curve_row(name, c) for name, c in sorted(doc["curves"].items())],
    )


def _sigma(sigma: float | None) -> str:
    """A curve's residual sigma as archived: of weighted fits a factor on the points'
    uncertainties (calib_core.thermal.Curve), no unit to convert."""
    import math

    return "-" if sigma is None or not math.isfinite(sigma) else f"{sigma:.3g}"


def _curve_row(name: str, curve: dict[str, Any]) -> list[str]:
    """One archived curve (SI) in `name`'s display unit (a linear scale: the coefficients
    of every order scale alike)."""
    from pipelines.reports.display import quantity, shown

    coef = ", ".join(quantity(name, c, 4) for c in curve["coef"])
    return [
        name,
        str(len(curve["coef"]) - 1),
        f"{coef} ({shown(name, 0.0).unit})",
        _sigma(curve.get("sigma")),
        str(curve.get("n_points", "-")),
        _hyst(name, curve.get("hysteresis")),
    ]


@thermal_app.command("export")
def thermal_export(
    serial: str,
    output: Path,
    fmt: Annotated[str, typer.Option("--format", help="json, px4 or ardupilot")] = "json",
    at: AtOpt = None,
    instance: Annotated[int, typer.Option(help="PX4 sensor instance / ArduPilot IMU number.")] = -1,
    device_id: DeviceIdOpt = None,
    rotation: RotationOpt = None,
    vehicle_id: VehicleIdOpt = 1,
    archive: ArchiveOpt = None,
) -> None:
    """Write SERIAL's calibration and thermal model for firmware (docs/exports.md)."""
    from pipelines import exports
    from pipelines.apply import load_compensation
    from storage import queries

    arch = open_archive(archive)
    cal, _, model, facts = _run(load_compensation, arch, serial, at_instant(at))
    if model is None:
        fail(f"{serial} has no thermal model: run `calib thermal fit {serial}` first")
    header = f"{serial} calibration {facts['run_id']} thermal model {facts['thermal_model_id']}"
    if fmt == "json":
        doc = exports.canonical_json(
            model, queries.export_calibration(arch, facts["run_id"]), {"serial": serial}
        )
        exports.write_json(output, doc)
    elif fmt in ("px4", "ardupilot"):
        archived = queries.run_summary(arch, facts["run_id"]).calibration
        ingest = archived.step_statistics("ingest")
        target = (instance, device_id, rotation, vehicle_id)
        said = (serial, facts["run_id"], header)
        text = _run(_firmware_file, fmt, model, cal, ingest, target, said)
        output.write_text(text, encoding="ascii")
    else:
        fail(f"unknown export format {fmt!r}; expected json, px4 or ardupilot")
    err.print(f"wrote {output}")


def _firmware_file(
    fmt: str,
    model: Any,  # noqa: ANN401 - calib_core.thermal.ThermalModel
    cal: Any,  # noqa: ANN401 - calib_core.calibration.Calibration
    ingest: dict[str, Any],
    target: tuple[int, int | None, str | None, int],
    said: tuple[str, str, str],
) -> str:
    """The PX4 / ArduPilot thermal file's text: device ids from the log (the ingest step's
    statistics `ingest`) or the option (else refused), rotated into the firmware's axes,
    with the header of what to set.

    `target`: (instance, device id, rotation, vehicle id) as given; `said`: (serial, the
    calibration's run, the line naming the calibration and thermal model)."""
    from pipelines import autopilot, exports

    instance, device_id, rotation, vehicle_id = target
    rot = autopilot.rotation(rotation, fmt)
    recorded = autopilot.recorded_devices(ingest)
    common = {
        "unit": said[0],
        "run": said[1],
        "model_range": (model.t_min, model.t_max),
        "rot": rot,
    }
    if fmt == "px4":
        acc_id, gyr_id, source = autopilot.px4_device_ids(recorded, device_id, device_id)
        i = max(instance, 0)
        rows = exports.px4_parameters(
            model, cal, instance=i, accel_id=acc_id, gyro_id=gyr_id, rot=rot
        )
        settings = [
            f"sets TC_A{i}_* / TC_G{i}_* of the sensors with device ids {acc_id} "
            f"(accelerometer) and {gyr_id} (gyro), {source}; TC_A_ENABLE = TC_G_ENABLE = 1"
        ]
        head = [said[2], *autopilot.header_lines("px4", settings=settings, **common)]
        return exports.px4_params_text(rows, header="\n".join(head), vehicle_id=vehicle_id)
    imu = instance if instance > 0 else recorded.get("imu", 0) + 1
    rows = exports.ardupilot_parameters(model, cal, imu=imu, rot=rot)
    settings = [f"sets INS_TCAL{imu}_* (IMU {imu}, the log's instance {imu - 1}); ENABLE = 1"]
    head = [said[2], *autopilot.header_lines("ardupilot", settings=settings, **common)]
    return exports.ardupilot_params_text(rows, header="\n".join(head))


@app.command("apply")
def apply(
    source: Annotated[
        Path, typer.Argument(help="Raw data: run folder, run.toml or MPU-6000 file.")
    ],
    output: Annotated[Path, typer.Argument(help="Calibrated samples: .parquet or .csv.")],
    serial: Annotated[str, typer.Option("--serial", help="The unit.")],
    at: AtOpt = None,
    archive: ArchiveOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Apply SERIAL's latest valid calibration (and thermal model) to new raw data."""
    from pipelines.apply import apply_calibration

    facts = _run(apply_calibration, open_archive(archive), serial, at_instant(at), source, output)
    for message in facts["warnings"]:
        warn(message)
    if as_json:
        print_json(facts)
        return
    shown = {k: v for k, v in facts.items() if k != "warnings"}
    print_facts(shown, "Calibration applied", paths=("output",))


@app.command("trend")
def trend(
    serial: str,
    param: str,
    plot: PlotOpt = None,
    profile: Annotated[str | None, typer.Option(help="Tolerance profile for the band.")] = None,
    archive: ArchiveOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """PARAM of SERIAL against calibration date: trend and when it leaves tolerance."""
    from pipelines.trends import trend_report

    rep = _run(trend_report, open_archive(archive), serial, param, profile=profile, plot=plot)
    if as_json:
        print_json({"summary": rep["summary"], "rows": frame_records(rep["table"])})
        return
    from pipelines.commands.query import displayed
    from pipelines.reports.display import quantity, shown, with_unit

    # SI: in the display unit, as `calib show` prints it
    table = displayed(rep["table"].assign(unit=None), param)
    table["fitted"] = [quantity(param, v) for v in table["fitted"]]
    print_frame(table, f"{param} of {serial}")
    summary = dict(rep["summary"])
    unit = summary["unit"] = shown(param, 0.0).unit
    # every number with its display unit (a slope per year: the value's unit per year)
    slope = shown(param, summary["slope_per_year"], summary["slope_std_per_year"])
    summary["slope_per_year"] = with_unit(slope.value, unit)
    summary["slope_std_per_year"] = with_unit(slope.u or "-", unit)
    limits = " .. ".join(quantity(param, v, 4) for v in summary["tolerance"])
    summary["tolerance"] = with_unit(limits, unit)
    print_facts(summary, f"Trend of {param}", paths=("plot",))


@app.command("fleet")
def fleet(
    model: str,
    param: str,
    bin_c: Annotated[float, typer.Option("--bin", help="Temperature bin width, deg C.")] = 5.0,
    plot: PlotOpt = None,
    archive: ArchiveOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """PARAM across every unit of device MODEL, per temperature bin."""
    from pipelines.trends import fleet_report

    table = _run(fleet_report, open_archive(archive), model, param, bin_c=bin_c, plot=plot)
    if as_json:
        print_json(frame_records(table))
        return
    from pipelines.reports.display import quantity, shown

    table = table.copy()  # SI: in the display unit, as `calib show` prints it
    for column in ("mean", "std", "median", "p05", "p95", "low", "high"):
        table[column] = [quantity(param, v) for v in table[column]]
    print_frame(table, f"{param} across {model} ({shown(param, 0.0).unit})")
    if plot is not None:
        err.print(f"plot: {plot}")
