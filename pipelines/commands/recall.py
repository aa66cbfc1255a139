"""`calib due --before DATE` (also `calib query due`), the CLI: units to recall, each with
its recalibration interval from its own and its fleet's drift (pipelines/recall.py,
docs/interval.md).
"""

from __future__ import annotations

from datetime import date
from typing import Annotated

import typer

from pipelines.cli_shared import ArchiveOpt, app, fail, fail_on, open_archive, print_frame
from pipelines.commands.query import Format, FormatOpt, emit, query_app

DUE_COLUMNS = ["due", "serial", "model", "run_id", "started_at", "verdict", "interval_months",
               "interval_days",
               "limiting_parameter", "reliability", "method", "owner"]  # fmt: skip

TABLE_COLUMNS = ["serial", "run_id", "calibrated", "due", "interval_months",
                 "limiting_parameter", "method", "last_verdict", "interval_days", "model",
                 "reliability", "owner"]  # fmt: skip


@app.command("due")
@query_app.command("due")
def due(
    before: Annotated[
        str | None, typer.Option("--before", help="List units due on or before this date.")
    ] = None,
    archive: ArchiveOpt = None,
    fmt: FormatOpt = Format.table,
) -> None:
    """Units due for recalibration: last calibration, interval from measured drift, owner."""
    import pandas as pd

    from pipelines.recall import recall_list

    try:
        day = None if before is None else date.fromisoformat(before)
    except ValueError:
        fail(f"--before: expected a date YYYY-MM-DD, got {before!r}")
    with fail_on(LookupError, ValueError):
        rows = recall_list(open_archive(archive), day)
    df = pd.DataFrame(rows, columns=DUE_COLUMNS) if rows else pd.DataFrame(columns=DUE_COLUMNS)
    title = "Units due" + ("" if before is None else f" by {before}")
    if fmt is Format.table and not df.empty:
        # The recall first (unit, last calibration, due date, interval): a narrow terminal
        # leaves out columns from the right; dates whole.
        day = [t.date().isoformat() for t in df["started_at"]]
        table = df.assign(calibrated=day, limiting_parameter=df["limiting_parameter"].fillna("-"))
        table = table.rename(columns={"verdict": "last_verdict"})
        table = table[TABLE_COLUMNS]
        print_frame(table, title, whole=("due", "calibrated"))
        return
    emit(df, fmt, title)
