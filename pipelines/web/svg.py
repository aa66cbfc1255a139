"""Server-side SVG charts for the archive browser: no JavaScript, prints as drawn.

Hand-built SVG (a chart costs well under a millisecond; matplotlib's SVG backend
takes tens of milliseconds a figure). Every text that reaches the SVG goes
through markupsafe's escape; numbers are formatted by this module. Values are in
whatever unit the caller gives (the pages pass lab display units).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import TYPE_CHECKING

from markupsafe import Markup, escape

if TYPE_CHECKING:  # numpy imported by the charts that need it (not at the server's start)
    import numpy as np

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
COLOURS = ("#c0392b", "#27ae60", "#2c6fbb", "#8e44ad", "#d68910", "#16a085")


def days(t: datetime) -> float:
    """Days since 1970-01-01 UTC (float)."""
    return (t - EPOCH).total_seconds() / 86400.0


def _num(v: float) -> str:
    return f"{v:.1f}"


def label(v: float) -> str:
    """A tick or value label: 4 significant digits, no trailing noise."""
    if v == 0 or not math.isfinite(v):
        return "0" if v == 0 else str(v)
    return f"{v:.4g}"


def tick_labels(ticks: Sequence[float]) -> list[str]:
    """Labels of the ticks with as many significant digits (4..12) as keep them distinct."""
    for digits in range(4, 13):
        out = [
            "0" if t == 0 or abs(t) < 1e-12 * max(map(abs, ticks)) else f"{t:.{digits}g}"
            for t in ticks
        ]
        if len(set(out)) == len(out):
            return out
    return out


def nice_ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    """About n round tick values covering [lo, hi]."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo]
    raw = (hi - lo) / n
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step) * step
    return [first + i * step for i in range(int((hi - first) / step + 1e-9) + 1)]


def span(values: Sequence[float], pad: float = 0.06) -> tuple[float, float]:
    """(low, high) of the finite values, widened by `pad` of their range each side."""
    v = [x for x in values if x is not None and math.isfinite(x)]
    if not v:
        return 0.0, 1.0
    lo, hi = min(v), max(v)
    if hi == lo:
        d = abs(lo) * 0.1 or 1.0
        return lo - d, hi + d
    d = (hi - lo) * pad
    return lo - d, hi + d


LABEL_GAP = 13.0  # px between the baselines of two text lines of a chart (11 px font)


@dataclass
class Chart:
    """A plot area with linear axes; elements are added as SVG strings."""

    x_range: tuple[float, float]
    y_range: tuple[float, float]
    title: str = ""
    y_label: str = ""
    x_label: str = ""
    width: int = 720
    height: int = 280
    margin: tuple[int, int, int, int] = (46, 34, 40, 70)  # top, right, bottom, left
    parts: list[str] = field(default_factory=list)

    def x(self, v: float) -> float:
        lo, hi = self.x_range
        top, right, bottom, left = self.margin
        return left + (v - lo) / (hi - lo) * (self.width - left - right)

    def y(self, v: float) -> float:
        lo, hi = self.y_range
        top, right, bottom, left = self.margin
        return self.height - bottom - (v - lo) / (hi - lo) * (self.height - top - bottom)

    def clip_y(self, v: float) -> float:
        return min(max(v, self.y_range[0]), self.y_range[1])

    def axes(self, x_ticks: list[tuple[float, str]] | None = None) -> None:
        top, right, bottom, left = self.margin
        x0, x1 = left, self.width - right
        y0, y1 = self.height - bottom, top
        p = self.parts
        p.append(f'<rect x="{x0}" y="{y1}" width="{x1 - x0}" height="{y0 - y1}" class="frame"/>')
        y_ticks = nice_ticks(*self.y_range)
        for t, text in zip(y_ticks, tick_labels(y_ticks), strict=True):
            yy = _num(self.y(t))
            p.append(f'<line x1="{x0}" x2="{x1}" y1="{yy}" y2="{yy}" class="grid"/>')
            p.append(
                f'<text x="{x0 - 4}" y="{yy}" class="tick" text-anchor="end" '
                f'dominant-baseline="middle">{escape(text)}</text>'
            )
        if x_ticks is None:
            ticks = nice_ticks(*self.x_range, n=6)
            x_ticks = list(zip(ticks, tick_labels(ticks), strict=True))
        for t, text in x_ticks:
            xx = _num(self.x(t))
            p.append(f'<line x1="{xx}" x2="{xx}" y1="{y0}" y2="{y0 + 4}" class="axis"/>')
            p.append(
                f'<text x="{xx}" y="{y0 + 16}" class="tick" text-anchor="middle">'
                f"{escape(text)}</text>"
            )
        if self.title:
            p.append(f'<text x="{x0}" y="16" class="title">{escape(self.title)}</text>')
        if self.y_label:
            p.append(
                f'<text x="14" y="{(y0 + y1) / 2:.0f}" class="tick" text-anchor="middle" '
                f'transform="rotate(-90 14 {(y0 + y1) / 2:.0f})">'
                f"{escape(self.y_label)}</text>"
            )
        if self.x_label:
            p.append(
                f'<text x="{(x0 + x1) / 2:.0f}" y="{self.height - 4}" class="tick" '
                f'text-anchor="middle">{escape(self.x_label)}</text>'
            )

    def hline(self, v: float, cls: str = "limit", text: str = "") -> None:
        if not (math.isfinite(v) and self.y_range[0] <= v <= self.y_range[1]):
            return
        top, right, bottom, left = self.margin
        yy = _num(self.y(v))
        self.parts.append(
            f'<line x1="{left}" x2="{self.width - right}" y1="{yy}" y2="{yy}" class="{cls}"/>'
        )
        if text:
            y_text = self._label_y(float(yy))
            self.parts.append(
                f'<text x="{self.width - right - 2}" y="{y_text:.1f}" '
                f'class="tick {cls}-text" text-anchor="end">{escape(text)}</text>'
            )

    def _label_y(self, y_line: float) -> float:
        """Where a line's label goes: just above the line, else just below it when that
        would overprint another label or the title (their baselines at least LABEL_GAP apart)."""
        used = getattr(self, "_label_ys", [16.0])  # the title's baseline
        for y in (y_line - 3.0, y_line + LABEL_GAP):
            if all(abs(y - u) >= LABEL_GAP for u in used):
                break
        else:
            y = max(used) + LABEL_GAP
        self._label_ys = [*used, y]
        return y

    def polyline(
        self, xs: Sequence[float], ys: Sequence[float], cls: str, colour: str = ""
    ) -> None:
        pts = " ".join(self._points(xs, ys))
        style = f' style="stroke:{colour}"' if colour else ""
        self.parts.append(f'<polyline points="{pts}" class="{cls}"{style}/>')

    def _points(self, xs: Sequence[float], ys: Sequence[float]) -> list[str]:
        """The "x,y" pixels (1 decimal) of each point with a finite y (clipped to the
        y range): `x`, `clip_y` and `y` over whole arrays, the same arithmetic."""
        import numpy as np  # the chart modules' pages load it anyway; `calib serve` starts without

        if len(xs) != len(ys):
            raise ValueError(f"{len(xs)} x values against {len(ys)} y values")
        a, b = np.asarray(xs, dtype=float), np.asarray(ys, dtype=float)
        keep = np.isfinite(b)
        a, b = a[keep], np.minimum(np.maximum(b[keep], self.y_range[0]), self.y_range[1])
        (x_lo, x_hi), (y_lo, y_hi) = self.x_range, self.y_range
        top, right, bottom, left = self.margin
        px = left + (a - x_lo) / (x_hi - x_lo) * (self.width - left - right)
        py = self.height - bottom - (b - y_lo) / (y_hi - y_lo) * (self.height - top - bottom)
        return [f"{u:.1f},{v:.1f}" for u, v in zip(px.tolist(), py.tolist(), strict=True)]

    def band(self, xs: Sequence[float], lo: Sequence[float], hi: Sequence[float]) -> None:
        up = [f"{self.x(a):.1f},{self.y(self.clip_y(b)):.1f}" for a, b in zip(xs, hi, strict=True)]
        down = [
            f"{self.x(a):.1f},{self.y(self.clip_y(b)):.1f}"
            for a, b in zip(reversed(xs), reversed(lo), strict=True)
        ]
        self.parts.append(f'<polygon points="{" ".join(up + down)}" class="band"/>')

    def point(
        self,
        xv: float,
        yv: float,
        err: float | None,
        title: str,
        href: str | None,
        cls: str = "pt",
        colour: str = "",
    ) -> None:
        xx, yy = self.x(xv), self.y(self.clip_y(yv))
        style = f' style="fill:{colour};stroke:{colour}"' if colour else ""
        body = ""
        if err is not None and math.isfinite(err) and err > 0:
            y_lo, y_hi = self.y(self.clip_y(yv - err)), self.y(self.clip_y(yv + err))
            body += (
                f'<line x1="{xx:.1f}" x2="{xx:.1f}" y1="{y_lo:.1f}" y2="{y_hi:.1f}" '
                f'class="err"{style}/>'
            )
        body += (
            f'<circle cx="{xx:.1f}" cy="{yy:.1f}" r="3.5" class="{cls}"{style}>'
            f"<title>{escape(title)}</title></circle>"
        )
        if href:
            body = f'<a href="{escape(href)}">{body}</a>'
        self.parts.append(body)

    def legend(self, items: Sequence[tuple[str, str]]) -> None:
        """(class or colour, text) entries in a row under the title."""
        x = self.margin[3]
        for cls, text in items:
            attr = f'style="fill:{cls}"' if cls.startswith("#") else f'class="{cls}"'
            self.parts.append(
                f'<rect x="{x}" y="24" width="10" height="10" {attr}/>'
                f'<text x="{x + 14}" y="33" class="tick">{escape(text)}</text>'
            )
            x += int(6.2 * len(text)) + 30

    def svg(self, aria: str) -> Markup:
        body = "".join(self.parts)
        return Markup(
            f'<svg xmlns="http://www.w3.org/2000/svg" class="chart" role="img" '
            f'viewBox="0 0 {self.width} {self.height}" width="{self.width}" '
            f'height="{self.height}" aria-label="{escape(aria)}">{body}</svg>'
        )


def date_ticks(lo: float, hi: float, n: int = 6) -> list[tuple[float, str]]:
    """Ticks on a day axis labelled YYYY-MM-DD (or YYYY-MM over long spans)."""
    import numpy as np

    fmt = "%Y-%m" if hi - lo > 400 else "%Y-%m-%d"
    return [(t, (EPOCH + timedelta(days=t)).strftime(fmt)) for t in np.linspace(lo, hi, n)]


@dataclass
class TrendPoint:
    when: datetime
    value: float
    std: float | None
    title: str
    href: str | None = None
    failed: bool = False


def trend_chart(
    points: Sequence[TrendPoint],
    *,
    title: str,
    unit: str,
    fit: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    limits: tuple[float, float] = (-math.inf, math.inf),
    until: float | None = None,
) -> Markup:
    """Values against calibration date with their uncertainty, a fitted line with its band
    (days, centre, half-width) and the tolerance band (dashed)."""
    xs = [days(p.when) for p in points]
    x_hi = max(xs + ([until] if until is not None else []))
    x_lo = min(xs)
    if x_hi - x_lo < 30.0:  # one date: a month either side, not a fraction of 50 years
        x_lo, x_hi = x_lo - 30.0, x_hi + 30.0
    x_range = span([x_lo, x_hi], 0.04)
    ys = [p.value for p in points] + [p.value + (p.std or 0) for p in points]
    ys += [p.value - (p.std or 0) for p in points]
    if fit is not None:
        ys += list(fit[1] - fit[2]) + list(fit[1] + fit[2])
    data_lo, data_hi = span(ys, 0.0)
    reach = 4.0 * max(data_hi - data_lo, abs(data_hi) * 1e-9, 1e-300)
    shown = [v for v in limits if math.isfinite(v) and data_lo - reach <= v <= data_hi + reach]
    chart = Chart(x_range, span(ys + shown), title=title, y_label=unit)
    chart.axes(date_ticks(*x_range))
    far = [label(v) for v in limits if math.isfinite(v) and v not in shown]
    if far:  # a band far wider than the data would flatten it: say where it is instead
        # on its own line under the title (a long title reaches the right edge)
        chart.parts.append(
            f'<text x="{chart.width - chart.margin[1]}" y="{16 + LABEL_GAP}" '
            'text-anchor="end" '
            f'class="tick limit-text">tolerance {escape(" / ".join(far))} '
            "outside the plotted range</text>"
        )
    if fit is not None:
        t, centre, half = fit
        chart.band(list(t), list(centre - half), list(centre + half))
        chart.polyline(list(t), list(centre), "fit")
    for lim, name in zip(limits, ("low", "high"), strict=True):
        chart.hline(lim, "limit", f"tolerance {name} {label(lim)}")
    for p, xv in zip(points, xs, strict=True):
        chart.point(xv, p.value, p.std, p.title, p.href, "pt fail" if p.failed else "pt")
    legend = [("pt", "calibration (± u)")]
    if fit is not None:
        legend.append(("band", "trend, 95 % band"))
    chart.legend(legend)
    return chart.svg(title)


def sparkline(values: Sequence[float], width: int = 120, height: int = 24) -> Markup:
    """A small line of the values (no axes), for tables."""
    v = [x for x in values if x is not None and math.isfinite(x)]
    if len(v) < 2:
        return Markup("")
    lo, hi = span(v, 0.1)
    step = (width - 4) / (len(v) - 1)
    pts = " ".join(
        f"{2 + i * step:.1f},{height - 2 - (x - lo) / (hi - lo) * (height - 4):.1f}"
        for i, x in enumerate(v)
    )
    return Markup(
        f'<svg xmlns="http://www.w3.org/2000/svg" class="spark" width="{width}" '
        f'height="{height}" aria-hidden="true"><polyline points="{pts}"/></svg>'
    )


def residual_chart(
    rows: Sequence[dict], sensor: str, unit: str, factor: float, limits: dict[str, float]
) -> Markup:
    """Residual mean per segment and axis (dots, std as whiskers); mean limits dashed."""
    rows = [r for r in rows if r.get("sensor") == sensor]
    if not rows:
        return Markup("")
    vals = [m * factor for r in rows for m in r["mean"]]
    vals += [(m + s) * factor for r in rows for m, s in zip(r["mean"], r["std"], strict=True)]
    vals += [(m - s) * factor for r in rows for m, s in zip(r["mean"], r["std"], strict=True)]
    lim = limits.get(f"{sensor}_mean")
    if lim is not None:
        vals += [lim * factor, -lim * factor]
    name = "Accelerometer" if sensor == "acc" else "Gyro"
    chart = Chart(
        (-0.5, len(rows) - 0.5),
        span(vals),
        title=f"{name} residuals per segment",
        y_label=unit,
        margin=(40, 16, 44, 70),
    )
    chart.axes([(i, str(r["segment"])) for i, r in enumerate(rows)])
    chart.hline(0.0, "zero")
    if lim is not None:
        chart.hline(lim * factor, "limit", "mean limit")
        chart.hline(-lim * factor, "limit")
    for i, r in enumerate(rows):
        for k, axis in enumerate("xyz"):
            m, s = r["mean"][k] * factor, r["std"][k] * factor
            chart.point(
                i + (k - 1) * 0.22,
                m,
                s,
                f"{r['segment']} {axis}: {label(m)} ± {label(s)} {unit}",
                None,
                "pt",
                COLOURS[k],
            )
    chart.legend([(COLOURS[k], f"{a} mean (± std)") for k, a in enumerate("xyz")])
    return chart.svg(f"{name} residuals")


def histogram(
    values: Sequence[float],
    *,
    title: str,
    unit: str,
    limits: tuple[float, float] = (-math.inf, math.inf),
    bins: int = 20,
) -> Markup:
    """Distribution of values (bars) with the tolerance band (dashed verticals)."""
    import numpy as np

    v = np.asarray([x for x in values if math.isfinite(x)], dtype=float)
    if v.size == 0:
        return Markup("")
    lo, hi = span(list(v) + [x for x in limits if math.isfinite(x)], 0.02)
    counts, edges = np.histogram(v, bins=bins, range=(lo, hi))
    chart = Chart(
        (lo, hi),
        (0.0, max(1.0, float(counts.max()) * 1.1)),
        title=title,
        y_label="units",
        x_label=unit,
    )
    chart.axes()
    for c, a, b in zip(counts, edges[:-1], edges[1:], strict=True):
        if c:
            x0, x1, y0 = chart.x(a), chart.x(b), chart.y(float(c))
            chart.parts.append(
                f'<rect x="{x0:.1f}" y="{y0:.1f}" width="{max(x1 - x0 - 1, 1):.1f}" '
                f'height="{chart.y(0.0) - y0:.1f}" class="bar"><title>{int(c)} unit(s) in '
                f"{escape(label(a))} .. {escape(label(b))} {escape(unit)}</title></rect>"
            )
    top, bottom = chart.margin[0], chart.height - chart.margin[2]
    for lim in limits:
        if math.isfinite(lim) and lo <= lim <= hi:
            xx = _num(chart.x(lim))
            chart.parts.append(
                f'<line x1="{xx}" x2="{xx}" y1="{top}" y2="{bottom}" class="limit"/>'
            )
    return chart.svg(title)


def curve_chart(
    temps: np.ndarray,
    curves: dict[str, tuple[np.ndarray, np.ndarray]],
    points: dict[str, list[tuple[float, float]]],
    *,
    title: str,
    unit: str,
) -> Markup:
    """Thermal curves (value against deg C, 2-std band) of a few parameters, with the
    campaign points they were fitted to."""
    ys = [y for c, s in curves.values() for y in (*(c - 2 * s), *(c + 2 * s))]
    ys += [y for pts in points.values() for _, y in pts]
    chart = Chart(
        span(list(temps), 0.02),
        span(ys),
        title=title,
        y_label=unit,
        x_label="temperature (deg C)",
    )
    chart.axes()
    for k, (name, (centre, std)) in enumerate(curves.items()):
        colour = COLOURS[k % len(COLOURS)]
        chart.band(list(temps), list(centre - 2 * std), list(centre + 2 * std))
        chart.polyline(list(temps), list(centre), "fit", colour)
        for t, y in points.get(name, []):
            chart.point(
                t, y, None, f"{name} at {label(t)} deg C: {label(y)} {unit}", None, "pt", colour
            )
    chart.legend([(COLOURS[k % len(COLOURS)], n) for k, n in enumerate(curves)])
    return chart.svg(title)


def error_chart(
    t: Sequence[float],
    series: dict[str, tuple[Sequence[float], Sequence[float]]],
    *,
    title: str,
    unit: str,
    outage: float | None = None,
    limit: float | None = None,
) -> Markup:
    """Navigation errors against time: each output's 1 sigma (solid) and 95 % (dashed)
    line, the start of the outage (vertical) and a limit (dashed, red)."""
    ys = [y for s, p in series.values() for y in (*s, *p)] + ([limit] if limit else [])
    chart = Chart(span(list(t), 0.02), span([0.0, *ys]), title=title, y_label=unit,
                  x_label="time (s)")  # fmt: skip
    chart.axes()
    if outage is not None:
        xx = _num(chart.x(outage))
        top, _, bottom, _ = chart.margin
        chart.parts.append(
            f'<line x1="{xx}" x2="{xx}" y1="{top}" y2="{chart.height - bottom}" class="zero"/>'
        )
    if limit is not None:
        chart.hline(limit, "limit", f"limit {label(limit)} {unit}")
    for k, (sigma, p95) in enumerate(series.values()):
        colour = COLOURS[k % len(COLOURS)]
        chart.polyline(list(t), list(sigma), "fit", colour)
        chart.polyline(list(t), list(p95), "fit p95", colour)
    chart.legend([(COLOURS[k % len(COLOURS)], n) for k, n in enumerate(series)])
    return chart.svg(title)
