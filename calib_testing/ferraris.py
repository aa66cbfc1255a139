"""imucal's real Ferraris example session (shared/realdata/imucal_ferraris) as Recordings.

One continuous 102.4 Hz recording in m/s^2 and deg/s, cut by its section list into six
static faces (x_p = x up, x_a = x down, ...) and one hand-made 360 deg turn about each axis
(x_rot, y_rot, z_rot); SOURCE.txt in the data folder says where it comes from.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from calib_core import params
from calib_core.recording import Recording
from calib_core.units import DEG

DATA = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "imucal_ferraris"
EXAMPLE_RATE_HZ = 102.4  # imucal examples/basic_ferraris.py
FACES = {"x_p": "x_up", "x_a": "x_dn", "y_p": "y_up", "y_a": "y_dn", "z_p": "z_up", "z_a": "z_dn"}


def section_label(name: str, part: Recording) -> str:
    """Our label of an imucal section: the face, or the turn with its sense from the data."""
    if name in FACES:
        return FACES[name]
    axis = name.split("_")[0]
    angle = np.trapezoid(part.gyr[:, params.AXIS_INDEX[axis]], part.t)
    return f"{axis}_{'ccw' if angle > 0 else 'cw'}"


def example_session() -> tuple[Recording, dict[str, dict[str, int]]]:
    """The example session whole (SI) and its section list (name -> sample start, end)."""
    df = pd.read_csv(DATA / "example_ferraris_session.csv")
    sections = json.loads((DATA / "example_ferraris_session_list.json").read_text())
    rec = Recording(
        df["n_samples"].to_numpy() / EXAMPLE_RATE_HZ,
        df[["acc_x", "acc_y", "acc_z"]].to_numpy(),
        df[["gyr_x", "gyr_y", "gyr_z"]].to_numpy() * DEG,
        source="example_ferraris_session.csv",
    )
    return rec, sections


def example_segments(rec: Recording, sections: dict[str, dict[str, int]]) -> dict[str, Recording]:
    """The sections of `rec` as labelled segments (`section_label`)."""
    segments = {}
    for name, span in sections.items():
        part = rec.select(np.arange(span["start"], span["end"]))
        label = section_label(name, part)
        segments[label] = part.with_label(label)
    return segments
