"""`calib inspect PATH`: what a data file or run folder holds, without archiving anything."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from pipelines.cli_shared import JsonOpt, app, out, print_json


@app.command("inspect")
def inspect_command(
    path: Path,
    as_json: JsonOpt = False,
) -> None:
    """Format, variant, columns with units, rate, gaps, temperature, segments, what is missing.

    Exit status 1 when the file or a run in the folder cannot be read (the
    error names the file, line or field).
    """
    from pipelines.inspect import inspect_path

    doc = inspect_path(path)
    if as_json:
        print_json(doc)
    else:
        _print(doc)
    errors = [doc.get("error")] + [r.get("error") for r in doc.get("runs", [])]
    if any(errors):
        raise typer.Exit(1)


def _say(text: str) -> None:
    out.print(text, highlight=False, markup=False, soft_wrap=True)


def _print(doc: dict[str, Any], indent: str = "") -> None:
    for key, value in doc.items():
        if key == "runs":
            for run in value:
                _say(f"{indent}run:")
                _print(run, indent + "  ")
        elif key == "sources" and isinstance(value, list):  # a log's IMU sources, one a line
            _say(f"{indent}sources:")
            for src in value:
                _say(
                    f"{indent}  {src['source']}: {_text(src['rate_hz'])} Hz, "
                    f"{src['samples']} samples, temperature {src['temperature']}"
                )
        elif key == "display":  # the MPU-6000 program's lines after each orientation
            _say(f"{indent}display:")
            for line in value:
                _say(f"{indent}  {line}")
        elif key == "segments" and isinstance(value, dict):
            _say(f"{indent}segments:")
            for label, seg in value.items():
                facts = ", ".join(f"{k} {_text(v)}" for k, v in seg.items() if k != "source")
                _say(f"{indent}  {label}: {facts}")
        else:
            _say(f"{indent}{key}: {_text(value)}")


def _text(value: Any) -> str:
    """A value as a person reads it: no Python reprs, '-' for nothing."""
    if value is None:
        return "-"
    if isinstance(value, dict):
        return ", ".join(f"{k} {_text(v)}" for k, v in value.items()) or "-"
    if isinstance(value, list | tuple):
        return ", ".join(_text(v) for v in value) or "none"
    return str(value)
