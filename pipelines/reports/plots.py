"""Report figures (matplotlib, Agg backend): what people would rather look at than read.

- residuals per segment (mean per axis with the std as whiskers, limits dashed);
- raw vs calibrated specific-force norm minus local g, sample by sample;
- Allan deviation, when the calibration's info holds one (static-bias procedure);
- thermal curves, when the calibration's info holds them.

Every function takes plain archived data (dicts, arrays) and returns a Figure;
`to_png_base64` / `to_svg` embed it in a report. No numerical method lives here:
the calibrated samples come from `Calibration.correct`.
"""

from __future__ import annotations

import base64
import io
from collections.abc import Mapping, Sequence
from typing import Any

import matplotlib

matplotlib.use("Agg")  # no display: reports are rendered on servers and in tests
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from calib_core.calibration import Calibration  # noqa: E402
from calib_core.units import DEG  # noqa: E402
from pipelines.reports.display import MG, RESIDUAL_UNITS  # noqa: E402

AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")


def residuals_figure(residuals: Sequence[Mapping[str, Any]], limits: Mapping[str, float]) -> Figure:
    """Residual mean per segment and axis (bars), its std (whiskers), limits (dashed).

    Parameters
    ----------
    residuals : SegmentResidual dicts (segment, sensor, mean (3,), std (3,), n), SI.
    limits : residual limits, SI: "acc_mean", "acc_std", "gyr_mean", "gyr_std".
    """
    sensors = [s for s in ("acc", "gyr") if any(r["sensor"] == s for r in residuals)]
    fig, axes = plt.subplots(len(sensors) or 1, 1, figsize=(8.0, 3.2 * max(len(sensors), 1)))
    axes = np.atleast_1d(axes)
    for ax, sensor in zip(axes, sensors, strict=False):
        unit, k = RESIDUAL_UNITS[sensor]
        rows = [r for r in residuals if r["sensor"] == sensor]
        x = np.arange(len(rows))
        for i, axis in enumerate("xyz"):
            ax.bar(
                x + (i - 1) * 0.27,
                [r["mean"][i] * k for r in rows],
                0.27,
                yerr=[r["std"][i] * k for r in rows],
                color=AXIS_COLOURS[i],
                alpha=0.8,
                capsize=2,
                label=f"{axis} mean (+- std)",
            )
        for key, style in ((f"{sensor}_mean", "--"), (f"{sensor}_std", ":")):
            if key in limits:
                for sign in (1, -1):
                    ax.axhline(sign * limits[key] * k, color="k", ls=style, lw=0.8)
        ax.axhline(0.0, color="0.6", lw=0.5)
        ax.set_xticks(x, [r["segment"] for r in rows], rotation=45, ha="right", fontsize=7)
        ax.set_ylabel(f"{sensor} residual ({unit})")
        ax.set_title(
            f"{'Accelerometer' if sensor == 'acc' else 'Gyro'} residuals per segment "
            "(dashed: mean limit, dotted: std limit)",
            fontsize=9,
        )
        ax.legend(fontsize=7, ncol=3, loc="upper right")
    fig.tight_layout()
    return fig


def norm_figure(
    segments: Sequence[str], acc: np.ndarray, cal: Calibration, gyr: np.ndarray
) -> Figure:
    """Specific-force norm minus local g, raw and calibrated, sample by sample.

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
    fig, ax = plt.subplots(figsize=(8.0, 3.4))
    n = np.arange(len(raw))
    ax.plot(n, raw, lw=0.5, color="tab:orange", label="raw")
    ax.plot(n, calibrated, lw=0.5, color="tab:blue", label="calibrated")
    labels = np.asarray(segments)
    starts = np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])
    for s in starts:
        ax.axvline(s, color="0.8", lw=0.5)
        ax.text(
            s,
            1.0,
            f" {labels[s]}",
            transform=ax.get_xaxis_transform(),
            fontsize=6,
            rotation=90,
            va="top",
        )
    ax.set_xlabel("sample")
    ax.set_ylabel("|f| - g (mg)")
    ax.set_title(f"Specific-force norm minus local g = {g:.5f} m/s^2", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    return fig


def allan_figure(allan: Mapping[str, Mapping[str, Any]]) -> Figure:
    """Allan deviation per sensor and axis, log-log.

    Parameters
    ----------
    allan : sensor -> {"taus": (K,), "adev": (K, 3)} (AllanResult.to_dict(), SI).
    """
    sensors = [s for s in ("acc", "gyr") if s in allan]
    fig, axes = plt.subplots(1, len(sensors), figsize=(8.0, 3.4), squeeze=False)
    for ax, sensor in zip(axes[0], sensors, strict=True):
        taus = np.asarray(allan[sensor]["taus"])
        adev = np.asarray(allan[sensor]["adev"]).reshape(len(taus), -1)
        unit, k = ("mg", 1.0 / MG) if sensor == "acc" else ("deg/h", 3600.0 / DEG)
        for i in range(adev.shape[1]):
            ax.loglog(taus, adev[:, i] * k, "o-", ms=2, color=AXIS_COLOURS[i % 3], label="xyz"[i])
        ax.set_xlabel("tau (s)")
        ax.set_ylabel(f"Allan deviation ({unit})")
        ax.set_title(f"{sensor} Allan deviation", fontsize=9)
        ax.grid(True, which="both", lw=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def thermal_figure(thermal: Mapping[str, Mapping[str, Any]]) -> Figure:
    """Parameter against temperature: measured points and the fitted curve.

    Parameters
    ----------
    thermal : parameter name -> {"temperature_c": [...], "value": [...]} and
        optionally "model_temperature_c", "model_value" (the fitted curve), SI.
    """
    names = list(thermal)
    cols = min(3, len(names))
    rows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(8.0, 2.6 * rows), squeeze=False)
    for ax, name in zip(axes.flat, names, strict=False):
        curve = thermal[name]
        ax.plot(curve["temperature_c"], curve["value"], "o", ms=3, label="measured")
        if "model_temperature_c" in curve and "model_value" in curve:
            ax.plot(curve["model_temperature_c"], curve["model_value"], "-", label="model")
        ax.set_title(name, fontsize=8)
        ax.set_xlabel("temperature (deg C)", fontsize=7)
        ax.tick_params(labelsize=6)
    for ax in list(axes.flat)[len(names) :]:
        ax.set_visible(False)
    fig.tight_layout()
    return fig


def to_png_base64(fig: Figure, dpi: int = 110) -> str:
    """The figure as a base64 PNG (for a data: URI); closes the figure."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


NAV_PANELS = (
    (("heading_deg", "roll_deg", "pitch_deg"), "attitude error (deg)"),
    (("horizontal_velocity_mps", "vertical_velocity_mps"), "velocity error (m/s)"),
    (("horizontal_position_m", "vertical_position_m"), "position error (m)"),
)


def navigation_figure(result: Mapping[str, Any]) -> Figure:
    """Attitude, velocity and position error against time: 1 sigma solid, 95 % dashed; the
    outage start and the position limit marked.

    Parameters
    ----------
    result : `pipelines.navigation.navfit`'s document (deg, m/s, m, s).
    """
    series = result["series"]
    t = np.asarray(series["t_s"])
    fig, axes = plt.subplots(1, 3, figsize=(10.0, 3.2))
    for ax, (keys, label) in zip(axes, NAV_PANELS, strict=True):
        for i, key in enumerate(keys):
            colour = AXIS_COLOURS[i]
            name = key.rsplit("_", 1)[0].replace("_", " ")
            ax.plot(t, series[key]["sigma"], "-", color=colour, lw=1, label=f"{name} 1 sigma")
            ax.plot(t, series[key]["p95"], "--", color=colour, lw=0.8, label=f"{name} 95 %")
        start = result["profile"].get("outage_start_s")
        if result["profile"]["aiding"] != "none" and start is not None:
            ax.axvline(start, color="grey", lw=0.6, ls=":")
        if label.startswith("position"):
            ax.axhline(result["position_limit_m"], color="black", lw=0.6, ls="-.")
        ax.set_xlabel("time (s)", fontsize=7)
        ax.set_ylabel(label, fontsize=7)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=5)
        ax.grid(True, lw=0.3)
    fig.suptitle(f"{result['serial']} on {result['profile']['name']}", fontsize=9)
    fig.tight_layout()
    return fig
