"""`calib impact EQUIPMENT_SERIAL --from D1 [--to D2] --error QUANTITY=VALUE`, the CLI: the
runs an out-of-tolerance reference affected, solved again with the true reference
(pipelines/impact.py, docs/impact.md). A dry run unless ``--apply``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli_shared import (
    ArchiveOpt,
    JsonOpt,
    app,
    err,
    fail,
    fail_on,
    open_archive,
    out,
    print_json,
    print_table,
)


@app.command("impact")
def impact_command(
    equipment_serial: str,
    since: Annotated[str, typer.Option("--from", help="First day of the period (YYYY-MM-DD).")],
    error: Annotated[
        str,
        typer.Option(
            "--error",
            help="QUANTITY=VALUE: rate_error_ppm (rate table, centrifuge), clock_error_ppm "
            "(DAQ), temperature_offset_c (thermal chamber), "
            "face_angle_error_arcsec[FACE,AXIS] (cube: face +x..-z tilted about axis x/y/z, "
            "e.g. 'face_angle_error_arcsec[+x,y]=30'); docs/impact.md.",
        ),
    ],
    until: Annotated[
        str | None, typer.Option("--to", help="Last day of the period (default: today).")
    ] = None,
    apply: Annotated[
        bool, typer.Option("--apply", help="Archive the re-solves as new sealed revisions.")
    ] = False,
    csv: Annotated[Path | None, typer.Option(help="Write the report as CSV to this file.")] = None,
    html: Annotated[Path | None, typer.Option(help="Write the report as an HTML page.")] = None,
    pdf: Annotated[
        Path | None, typer.Option(help="Write the report typeset as PDF (nonconformity record).")
    ] = None,
    archive: ArchiveOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Out-of-tolerance look-back: the runs made on EQUIPMENT_SERIAL in the period, solved
    again from their raw bytes with the reference corrected; verdicts before and after."""
    from calib_core.reference_errors import parse_error
    from pipelines.impact import applied_words, csv_report, html_report, impact, pdf_report
    from storage.queries import as_instant

    with fail_on(ValueError):
        err_ = parse_error(error)
        first = as_instant(since, "--from", end_of_day=False)
        last = as_instant(until, "--to", end_of_day=True)
    if last is not None and last < first:
        fail(f"--to {until} is before --from {since}: the period is empty")
    arch = open_archive(archive)
    with fail_on(LookupError, ValueError):
        doc = impact(arch, equipment_serial, err_, since, until, apply=apply)
    if csv is not None:
        csv.write_text(csv_report(doc), encoding="utf-8")
        err.print(f"wrote {csv}", soft_wrap=True)
    if html is not None:
        html.write_text(html_report(doc), encoding="utf-8")
        err.print(f"wrote {html}", soft_wrap=True)
    if pdf is not None:
        pdf.write_bytes(pdf_report(doc))
        err.print(f"wrote {pdf}", soft_wrap=True)
    if as_json:
        print_json(doc)
        _exit_if_not_written(doc)
        return
    # What the look-back is for first (the run, verdicts, what moved): a narrow terminal
    # leaves out columns from the right (print_table).
    rows = [
        [
            r["run_id"],
            r["serial"],
            r["started_at"][:10],
            f"{r['verdict_before']} -> {r['verdict_after'] or 'failed'}",
            "\n".join(
                (
                    [f"{r['temperature_c']['before']:g} -> {r['temperature_c']['after']:g} degC"]
                    if r.get("temperature_c")
                    else []
                )
                + [f"{m['name']} {m['change_in_U']:+.2f} U" for m in r["moved"][:3]]
            )  # fmt: skip
            or ("-" if r["affected"] else "not affected"),
            r.get("status", "dry run"),
            r["procedure"],
        ]
        for r in doc["runs"]
    ]
    columns = ["run_id", "serial", "started", "before -> after", "moved", "status", "procedure"]
    if not apply:  # every row a dry run: said once below the table
        columns.remove("status")
        rows = [r[:5] + r[6:] for r in rows]
    print_table(
        f"Impact of {doc['reason']}",
        columns,
        rows,
        facts=f"customer: {doc['customer'] or 'not recorded'}; "
        + (applied_words(doc) if apply else "dry run: nothing archived (--apply archives)"),
        whole=("started",),
    )
    for c in doc["campaigns"]:
        b, a = c["range_before"], c["range_after"]
        largest = c["moved"][0] if c["moved"] else None
        out.print(
            f"thermal model of {c['serial']} fitted again ({len(c['corrected'])} of "
            f"{len(c['runs'])} runs corrected): {b['t_min']:g} .. {b['t_max']:g} -> "
            f"{a['t_min']:g} .. {a['t_max']:g} degC"
            + (
                f"; largest change {largest['name']} {largest['change_in_U']:+.2f} U at "
                f"{largest['temperature_c']:g} degC"
                if largest
                else ""
            )
            + (f"; archived as model {c['model_id_after']}" if "model_id_after" in c else "")
            + (f"; {c['status']}: {c['error']}" if "error" in c else ""),
            markup=False,
        )
    for r in doc["runs"]:
        if "error" in r:
            out.print(f"{r['run_id']}: {r['error']}", markup=False)
    _exit_if_not_written(doc)


def _exit_if_not_written(doc: dict) -> None:
    """Exit 1 naming what an applied look-back did not write (a write that failed, a run
    that no longer solves): it never reports success it did not have."""
    if doc["not_written"]:
        err.print(
            f"not written: {', '.join(doc['not_written'])} (see each run's error above); "
            "run the same command again once the cause is fixed",
            markup=False,
            soft_wrap=True,
        )
        raise typer.Exit(1)
