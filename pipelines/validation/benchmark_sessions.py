"""Ground-truth benchmark, the public sessions: each real recording of the set processed as a
lab run and compared with its published reference values.

A session names its data folder (under the real-data root, `--realdata`), the files to take
from it, its run manifest (`sessions/` beside this module), the settings it is solved with
and its reference: per parameter the published value and either the tolerance the
reference itself allows (a datasheet's values are nominal, so its stability figures) or,
for a result published by another implementation, its standard uncertainty (`u`, None when
it states none), with their source. Each parameter is reported with ours, the reference,
the difference, our expanded U and whether they agree: within the tolerance, or E_n <= 1
(`compare.comparison_row`, k = 2, as `calib validate`). A session whose data are not found
says so; nothing is skipped silently.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from calib_core import params
from pipelines.ingest.run_loader import discover_runs, load_run
from pipelines.process import solve_loaded
from pipelines.validation.compare import comparison_row

SESSIONS = Path(__file__).with_name("sessions")


def run_session(session: Mapping[str, Any], realdata: Path) -> dict[str, Any]:
    """One session processed and compared with its reference (the document of the report)."""
    folder = Path(realdata) / session["data"]
    base = {"id": session["id"], "procedure": session["procedure"], "source": session["source"]}
    missing = [n for n in session["files"] if not (folder / n).is_file()]
    if missing:
        return {**base, "status": "not found", "reason": f"{folder}: no {', '.join(missing)}"}
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / session["id"]
        run.mkdir()
        for name in session["files"]:
            shutil.copyfile(folder / name, run / name)
        shutil.copyfile(SESSIONS / session["manifest"], run / "run.toml")
        loaded = load_run(discover_runs([run])[0])
        cal, _, _, budgets, _ = solve_loaded(loaded, settings=dict(session.get("settings", {})))
    rows = []
    for name, ref in session["reference"].items():
        p = cal.parameters[name]
        diff = p.value - float(ref["value"])
        row = {
            "parameter": name,
            "ours": p.value,
            "reference": float(ref["value"]),
            "difference": diff,
            "U": budgets[name].U if name in budgets else None,
            "tolerance": None,
            "e_n": None,
        }
        if "tolerance" in ref:
            row["tolerance"] = float(ref["tolerance"])
            row["within_tolerance"] = abs(diff) <= row["tolerance"]
        else:
            unit = params.unit_of(name)
            row["e_n"] = comparison_row(name, p.value, p.std, row["reference"], ref.get("u"), unit)[
                "e_n"
            ]
            row["within_tolerance"] = row["e_n"] is not None and row["e_n"] <= 1.0
        rows.append(row)
    return {**base, "status": "compared", "parameters": rows}


def run_sessions(set_doc: Mapping[str, Any], realdata: Path | None) -> list[dict[str, Any]]:
    """Every session of the set; without a real-data root each says it was not run."""
    out = []
    for session in set_doc.get("sessions", []):
        if realdata is None:
            out.append(
                {
                    "id": session["id"],
                    "procedure": session["procedure"],
                    "source": session["source"],
                    "status": "not run",
                    "reason": "no real-data folder given (--realdata DIR)",
                }
            )
        else:
            out.append(run_session(session, realdata))
    return out
