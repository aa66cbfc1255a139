"""`calib query ...`: the archive's questions (storage.queries) on the command line.

Every subcommand prints to stdout as a table (default), CSV or JSON
(``--format``); messages go to stderr. Exit codes: 0 answered (also with no
rows for a list), 1 nothing found for `latest`, 2 invalid input or unknown run.
"""

from __future__ import annotations

import json
import sys
from enum import StrEnum
from typing import TYPE_CHECKING, Annotated, Any

import typer

from pipelines.cli_shared import (
    ArchiveOpt,
    AtOpt,
    RevisionOpt,
    app,
    at_instant,
    err,
    fail_on,
    frame_records,
    open_archive,
    open_run,
    out,
    plain,
    print_frame,
    print_json,
    sub_app,
)

if TYPE_CHECKING:  # pandas loads in the commands that use it, not for `calib --help`
    import pandas as pd

query_app = sub_app(
    "Ask the archive: latest, lineage, lapsed, units, history, fleet, due (also `calib due`)."
)
app.add_typer(query_app, name="query")


class Format(StrEnum):
    table = "table"
    csv = "csv"
    json = "json"


FormatOpt = Annotated[Format, typer.Option("--format", help="table, csv or json.")]


def emit(df: pd.DataFrame, fmt: Format, title: str, param: str | None = None) -> None:
    """Print a DataFrame in the chosen format: JSON and CSV in SI, as queried; the table
    with parameter values in their display units (`pipelines.reports.display`), the
    parameter named by a ``name`` column or by `param`."""
    if fmt is Format.json:
        print_json(frame_records(df))
    elif fmt is Format.csv:
        df.to_csv(sys.stdout, index=False, date_format="%Y-%m-%dT%H:%M:%S%z")
    elif df.empty:
        err.print(f"{title}: no rows")
    else:
        print_frame(displayed(df, param), title)


def displayed(df: pd.DataFrame, param: str | None) -> pd.DataFrame:
    """`df` with its value / std / unit columns as people read them: display unit, the
    uncertainty to two significant digits (column ``u``), the value to the same place."""
    from pipelines.reports.display import STANDARD_U, shown

    if not {"value", "std", "unit"} <= set(df.columns) or ("name" not in df and param is None):
        return df
    names = df["name"] if "name" in df else [param] * len(df)
    texts = [shown(n, v, u) for n, v, u in zip(names, df["value"], df["std"], strict=True)]
    out = df.copy()
    out["value"] = [t.value for t in texts]
    out["std"] = [t.u or "-" for t in texts]
    out["unit"] = [t.unit for t in texts]
    return out.rename(columns={"std": STANDARD_U})


def _ask(fn, archive: str | None, *args, **kwargs):  # noqa: ANN001, ANN202 - any query
    """`fn` (a `storage.queries` function) asked of the archive that `archive` names;
    exit 2 with its message on a bad value or nothing found."""
    arch = open_archive(archive)
    with fail_on(ValueError, LookupError):
        return fn(arch, *args, **kwargs)


@query_app.command("latest")
def latest(
    serial: str,
    at: AtOpt = None,
    archive: ArchiveOpt = None,
    fmt: FormatOpt = Format.table,
) -> None:
    """Parameters of the latest valid calibration of SERIAL as of a date (default now)."""
    from storage import queries

    df = _ask(queries.latest_valid, archive, serial, at_instant(at))
    if df.empty:  # still print the empty CSV header / JSON list for scripts
        err.print(f"no valid calibration of {serial!r}" + (f" as of {at}" if at else ""))
    emit(df, fmt, f"Latest valid calibration of {serial}")
    if df.empty:
        raise typer.Exit(1)


@query_app.command("lineage")
def lineage(
    run_id: str,
    param: str,
    revision: RevisionOpt = None,
    archive: ArchiveOpt = None,
    fmt: FormatOpt = Format.table,
) -> None:
    """Where PARAM of run RUN_ID comes from: raw files, steps, software, equipment, conditions."""
    import pandas as pd

    from storage import queries

    arch, run_id = open_run(archive, run_id)
    with fail_on(ValueError, LookupError):
        doc = queries.lineage(arch, run_id, param, revision)
    if fmt is Format.json:
        print_json(plain(doc))
        return
    if fmt is Format.csv:
        long = pd.DataFrame(_flatten(doc), columns=["section", "item", "field", "value"])
        long.to_csv(sys.stdout, index=False)
        return
    # What bears on PARAM only, wrapped to the terminal; --format json has the full record.
    from pipelines.reports.lineage import lineage_text

    sys.stdout.write(lineage_text(doc, param, width=max(out.width, 40)))


def _flatten(doc: dict[str, Any]) -> list[tuple[str, str, str, str]]:
    """(section, item, field, value) rows: lists get one item per element, dicts JSON values."""
    rows = []
    for section, body in doc.items():
        items = body if isinstance(body, list) else [body]
        if section == "parameter":
            items = [{"name": body["name"], **v} for v in body["values"]]
        for i, item in enumerate(items):
            for key, value in item.items():
                v = plain(value)
                text = json.dumps(v, sort_keys=True) if isinstance(v, dict | list) else str(v)
                rows.append((section, str(i), key, text))
    return rows


@query_app.command("lapsed")
def lapsed(
    equipment_serial: str,
    kind: Annotated[str | None, typer.Option(help="Equipment kind, e.g. rate_table.")] = None,
    archive: ArchiveOpt = None,
    fmt: FormatOpt = Format.table,
) -> None:
    """Runs made on EQUIPMENT_SERIAL while its own calibration had lapsed."""
    from storage import queries

    df = _ask(queries.lapsed_runs, archive, equipment_serial, kind)
    emit(df, fmt, f"Runs on {equipment_serial} after its calibration was due")


@query_app.command("units")
def units(
    model: Annotated[str | None, typer.Option(help="Device model.")] = None,
    date_from: Annotated[str | None, typer.Option("--from", help="Runs from this date.")] = None,
    date_to: Annotated[str | None, typer.Option("--to", help="Runs up to this date.")] = None,
    verdict: Annotated[str | None, typer.Option(help="pass or fail.")] = None,
    env_temp_min: Annotated[
        float | None, typer.Option("--env-temp-min", help="Lab temperature >= this, deg C.")
    ] = None,
    env_temp_max: Annotated[
        float | None, typer.Option("--env-temp-max", help="Lab temperature <= this, deg C.")
    ] = None,
    archive: ArchiveOpt = None,
    fmt: FormatOpt = Format.table,
) -> None:
    """Calibrated units by model, date range, lab temperature and verdict."""
    from storage import queries

    df = _ask(
        queries.units,
        archive,
        model=model,
        date_from=date_from,
        date_to=date_to,
        verdict=verdict,
        env_temp_min=env_temp_min,
        env_temp_max=env_temp_max,
    )
    emit(df, fmt, "Calibrated units")


@query_app.command("history")
def history(
    serial: str,
    param: str,
    superseded: Annotated[
        bool, typer.Option("--superseded", help="Also superseded revisions.")
    ] = False,
    archive: ArchiveOpt = None,
    fmt: FormatOpt = Format.table,
) -> None:
    """Values of PARAM of SERIAL over its calibrations, oldest first."""
    from storage import queries

    df = _ask(
        queries.serial_parameter_history, archive, serial, param, include_superseded=superseded
    )
    emit(df, fmt, f"{param} of {serial}", param)


@query_app.command("fleet")
def fleet(
    model: str,
    param: str,
    at: AtOpt = None,
    archive: ArchiveOpt = None,
    fmt: FormatOpt = Format.table,
) -> None:
    """PARAM across every unit of MODEL (each unit's latest valid calibration)."""
    from storage import queries

    df = _ask(queries.fleet, archive, model, param, at_instant(at))
    emit(df, fmt, f"{param} across {model}", param)
    if fmt is Format.table and not df.empty:
        from pipelines.reports.display import quantity, shown

        v = df["value"]  # SI: said in the display unit, as the table above
        err.print(
            f"{len(df)} values of {df['serial'].nunique()} units: median "
            f"{quantity(param, v.median())}, 5% {quantity(param, v.quantile(0.05))}, 95% "
            f"{quantity(param, v.quantile(0.95))} {shown(param, 0.0).unit}",
            markup=False,
            highlight=False,
        )
