"""`calib query due --before DATE`, the CLI: units to recall, each with its recalibration
interval from its own and its fleet's drift (pipelines/recall.py, docs/interval.md).
"""

from __future__ import annotations

from datetime import date
from typing import Annotated

import typer

from pipelines.cli_shared import ArchiveOpt, fail, open_archive
from pipelines.commands.query import Format, FormatOpt, emit, query_app

DUE_COLUMNS = ["due", "serial", "model", "run_id", "started_at", "verdict", "interval_months",
               "interval_days",
               "limiting_parameter", "reliability", "method", "owner"]  # fmt: skip


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
    try:
        rows = recall_list(open_archive(archive), day)
    except (LookupError, ValueError) as exc:
        fail(str(exc))
    df = pd.DataFrame(rows, columns=DUE_COLUMNS) if rows else pd.DataFrame(columns=DUE_COLUMNS)
    emit(df, fmt, "Units due" + ("" if before is None else f" by {before}"))
