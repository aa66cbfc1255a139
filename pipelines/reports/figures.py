"""The certificate's figures: self-contained SVG charts (pipelines.web.svg's `Chart`, the
charts of the archive browser), which the HTML embeds as images and Typst sets as vector
graphics in the PDF.

- residuals per segment and sensor (the run page's chart: mean per axis, std as whiskers,
  mean limits dashed);
- raw vs calibrated specific-force norm minus local g, sample by sample (drawn as the
  envelope of the samples in each sliver of the plot's width: the same picture as every
  sample, at a size that does not grow with the record);
- Allan deviation (log-log), when the calibration's info holds one (static bias);
- thermal curves, when the calibration's info holds them.

A chart costs milliseconds (matplotlib took tenths of a second a figure). No numerical
method lives here: the calibrated samples come from `Calibration.correct`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from markupsafe import escape

from calib_core.calibration import Calibration
from calib_core.units import DEG
from pipelines.reports.display import MG, RESIDUAL_UNITS
from pipelines.web import svg

# The chart classes of pipelines.web.svg, for a chart read outside the browser's page.
CSS = (
    "text{font-family:'DejaVu Sans',sans-serif;font-size:11px;fill:#333}"
    ".title{font-weight:bold;font-size:12px}"
    ".frame{fill:none;stroke:#9aa5b1}.grid{stroke:#e6eaee}.axis{stroke:#9aa5b1}"
    ".limit{stroke:#c0392b;stroke-dasharray:5 4;stroke-width:1.2}.limit-text{fill:#c0392b}"
    ".zero{stroke:#aaa}.fit{fill:none;stroke:#2c6fbb;stroke-width:1.6}"
    ".band{fill:#2c6fbb;fill-opacity:.14;stroke:none}.pt{fill:#1f3a5f;stroke:#1f3a5f}"
    ".err{stroke:#1f3a5f;stroke-width:1.2}.line{fill:none;stroke-width:0.8}"
    ".segment{stroke:#ccc;stroke-width:0.6}.segment-text{font-size:8px;fill:#555}"
)
RAW, CALIBRATED = "#e67e22", "#2c6fbb"


def standalone(chart: str) -> str:
    """An SVG chart of pipelines.web.svg with its style sheet inside (an image of its own)."""
    head, _, body = str(chart).partition(">")
    return f"{head}><style>{CSS}</style>{body}"


def residual_figures(
    residuals: Sequence[Mapping[str, Any]], limits: Mapping[str, float]
) -> dict[str, str]:
    """Residual mean per segment and axis with the std (the run page's chart), per sensor.

    Parameters
    ----------
    residuals : SegmentResidual dicts (segment, sensor, mean (3,), std (3,), n), SI.
    limits : residual limits, SI: "acc_mean", "acc_std", "gyr_mean", "gyr_std".
    """
    out = {}
    for sensor, name in (("acc", "Accelerometer"), ("gyr", "Gyro")):
        chart = svg.residual_chart(list(residuals), sensor, *RESIDUAL_UNITS[sensor], dict(limits))
        if chart:
            out[f"{name} residuals per segment"] = standalone(chart)
    return out


def envelope(y: np.ndarray, slivers: int) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of the minimum and maximum of `y` in each of about `slivers` runs of samples,
    in sample order: the polyline a plot `slivers` pixels wide draws of every sample."""
    n = len(y)
    if n <= 2 * slivers:
        return np.arange(n, dtype=float), y
    k = -(-n // slivers)  # samples per sliver
    m = -(-n // k)
    runs = np.pad(y, (0, m * k - n), mode="edge").reshape(m, k)
    first = np.arange(m) * k
    i_lo, i_hi = first + runs.argmin(axis=1), first + runs.argmax(axis=1)
    i_lo, i_hi = np.minimum(i_lo, n - 1), np.minimum(i_hi, n - 1)
    order = np.column_stack([np.minimum(i_lo, i_hi), np.maximum(i_lo, i_hi)]).ravel()
    return order.astype(float), y[order]


def norm_figure(segments: Sequence[str], acc: np.ndarray, cal: Calibration, gyr: np.ndarray) -> str:
    """Specific-force norm minus local g, raw and calibrated, sample by sample (mg).

    Parameters
    ----------
    segments : (N,) segment label of each sample.
    acc, gyr : (N, 3) raw samples, SI.
    cal : the calibration (its gravity is the reference level).
    """
    acc_cal, _ = cal.correct(acc, gyr)
    g = cal.gravity
    raw = (np.linalg.norm(acc, axis=1) - g) / MG
    calibrated = (np.linalg.norm(acc_cal, axis=1) - g) / MG
    finite = np.concatenate([raw[np.isfinite(raw)], calibrated[np.isfinite(calibrated)]])
    chart = svg.Chart(
        (0.0, max(len(raw) - 1, 1)),
        svg.span([float(finite.min()), float(finite.max())] if finite.size else [0.0]),
        title=f"Specific-force norm minus local g = {g:.5f} m/s^2",
        y_label="|f| - g (mg)",
        x_label="sample",
        margin=(40, 16, 40, 70),
    )
    chart.axes([(t, f"{t:.0f}") for t in svg.nice_ticks(*chart.x_range, n=6)])  # sample numbers
    labels = np.asarray(segments)
    top, bottom = chart.margin[0], chart.height - chart.margin[2]
    for s in np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]]) if len(labels) else []:
        xx = chart.x(float(s))
        chart.parts.append(
            f'<line x1="{xx:.1f}" x2="{xx:.1f}" y1="{top}" y2="{bottom}" class="segment"/>'
            f'<text x="{xx + 2:.1f}" y="{top + 2}" class="segment-text" '
            f'transform="rotate(90 {xx + 2:.1f} {top + 2})">{escape(str(labels[s]))}</text>'
        )
    slivers = chart.width - chart.margin[1] - chart.margin[3]
    for values, colour in ((raw, RAW), (calibrated, CALIBRATED)):
        xs, ys = envelope(values, slivers)
        chart.polyline(xs.tolist(), ys.tolist(), "line", colour)
    chart.legend([(RAW, "raw"), (CALIBRATED, "calibrated")])
    return standalone(chart.svg("Specific-force norm minus local g"))


def _decades(lo: float, hi: float) -> list[tuple[float, str]]:
    """Ticks at the powers of ten within [lo, hi] (log10 units), labelled 1e-3 ..."""
    return [(float(k), f"1e{k}") for k in range(math.ceil(lo), math.floor(hi) + 1)]


def allan_figures(allan: Mapping[str, Mapping[str, Any]]) -> dict[str, str]:
    """Allan deviation per sensor and axis, log-log.

    Parameters
    ----------
    allan : sensor -> {"taus": (K,), "adev": (K, 3)} (AllanResult.to_dict(), SI).
    """
    out = {}
    for sensor in ("acc", "gyr"):
        if sensor not in allan:
            continue
        taus = np.asarray(allan[sensor]["taus"], dtype=float)
        adev = np.asarray(allan[sensor]["adev"], dtype=float).reshape(len(taus), -1)
        unit, k = ("mg", 1.0 / MG) if sensor == "acc" else ("deg/h", 3600.0 / DEG)
        ok = (taus > 0)[:, None] & (adev > 0)
        lx, ly = np.log10(taus[ok.any(axis=1)]), np.log10(adev[ok] * k)
        if not lx.size:
            continue
        chart = svg.Chart(
            svg.span([lx.min(), lx.max()], 0.03),
            svg.span([ly.min(), ly.max()]),
            title=f"{sensor} Allan deviation",
            y_label=f"Allan deviation ({unit}), log",
            x_label="tau (s), log",
        )
        chart.axes(_decades(*chart.x_range))
        for i in range(adev.shape[1]):
            use = ok[:, i]
            xs, ys = np.log10(taus[use]), np.log10(adev[use, i] * k)
            chart.polyline(xs.tolist(), ys.tolist(), "line", svg.COLOURS[i % 3])
        chart.legend([(svg.COLOURS[i % 3], "xyz"[i]) for i in range(adev.shape[1])])
        out[f"Allan deviation ({sensor})"] = standalone(chart.svg(f"{sensor} Allan deviation"))
    return out


def thermal_figures(thermal: Mapping[str, Mapping[str, Any]]) -> dict[str, str]:
    """Each parameter against temperature: measured points and the fitted curve.

    Parameters
    ----------
    thermal : parameter name -> {"temperature_c": [...], "value": [...]} and
        optionally "model_temperature_c", "model_value" (the fitted curve), SI.
    """
    out = {}
    for name, curve in thermal.items():
        t, v = list(curve["temperature_c"]), list(curve["value"])
        mt, mv = list(curve.get("model_temperature_c", [])), list(curve.get("model_value", []))
        chart = svg.Chart(
            svg.span(t + mt, 0.04),
            svg.span(v + mv),
            title=name,
            y_label="value (SI)",
            x_label="temperature (deg C)",
            height=220,
        )
        chart.axes()
        if mt and len(mt) == len(mv):
            chart.polyline(mt, mv, "fit")
        for a, b in zip(t, v, strict=True):
            chart.point(a, b, None, f"{name} at {svg.label(a)} deg C", None)
        out[f"Thermal curve {name}"] = standalone(chart.svg(name))
    return out
