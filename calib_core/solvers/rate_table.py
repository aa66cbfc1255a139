"""Gyro rate-table calibration (docs/methods.md 2.4; IEEE Std 952 / 1431 practice).

Each rate point is the mean gyro output over the record window of one plateau
with the table turning at a known rate about one body axis. Per output channel i
the model is linear in the unknowns:

    mean_i - w_i = b_i + sum_{j in excited axes} M_ij w_j

solved by weighted least squares (weights 1 / sem^2), one channel at a time
(the channels' noises are independent). Exciting one axis j gives column j of M
(scale error M_jj and the cross-axis terms M_ij); exciting all three gives the
whole matrix. Reported besides the canonical parameters (Calibration.info):

- bias consistency: mean of the 0-rate points against the intercept fitted
  from the non-zero rates alone;
- scale-factor nonlinearity per axis: largest residual of the on-axis channel
  from the fitted line, over the full-scale output (1 + M_jj) * full_scale, ppm;
- scale-factor asymmetry per axis: (K+ - K-) / ((K+ + K-) / 2) in ppm, with K+
  and K- fitted over the positive and the negative rates with a shared bias.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib_core.calibration import Calibration, SegmentResidual
from calib_core.distributions import chi2_sf
from calib_core.params import AXES
from calib_core.recording import Recording
from calib_core.settings import Setting, Settings, SettingsIn
from calib_core.units import DEG, STANDARD_GRAVITY

# The procedure's settings (docs/procedures.md); its solver takes them typed.
SETTINGS = Settings(
    Setting("settle_s", "number", "s", 20.0,
            "settle time dropped from the start of each plateau", low=0.0),
    Setting("record_s", "number", "s", None,
            "record window after the settle (absent: to the plateau's end)", low=0.0,
            low_open=True),
    Setting("full_scale_dps", "number", "deg/s", None,
            "input full scale for the nonlinearity (absent: the largest rate)", low=0.0,
            low_open=True),
    Setting("gyro_bias", "text", "", "joint",
            "gyro bias fitted with the scale factors (joint) or fixed from the static run "
            "(static: the 0-rate points, or static_bias_dps)", choices=("joint", "static")),
    Setting("static_bias_dps", "list", "deg/s", None,
            "[x, y, z] bias of a separate static-bias run (gyro_bias = \"static\")", length=3),
    Setting("static_bias_std_dps", "list", "deg/s", None,
            "[x, y, z] standard uncertainty of static_bias_dps (absent: 0)", length=3),
    name="RateTableSettings",
)  # fmt: skip


def plateau_window(settings: SettingsIn) -> dict[str, float]:
    """``settle_s`` and ``record_s`` (s) of each plateau's record window from the run's
    settings (typed or a mapping; defaults filled in): the fit's and the held-out points'
    one window."""
    s = SETTINGS.parse(settings)
    return {k: float(v) for k in ("settle_s", "record_s") if (v := getattr(s, k)) is not None}


ZERO_RATE = 1e-6  # rad/s (0.2 deg/h): points below this count as 0-rate points


@dataclass(frozen=True)
class RatePoint:
    """One rate plateau reduced to means.

    axis : body axis on the table axis ("x", "y", "z").
    table_rate : reference rate from the table feedback, rad/s (signed).
    gyro_mean : (3,) mean gyro output, rad/s.
    gyro_sem : (3,) standard uncertainty of the mean, rad/s.
    n : number of samples averaged.
    label : plateau name, for messages and residuals.
    """

    axis: str
    table_rate: float
    gyro_mean: np.ndarray
    gyro_sem: np.ndarray
    n: int
    label: str | None = None

    def __post_init__(self) -> None:
        name = self.label or f"{self.axis} at {self.table_rate} rad/s"
        if self.axis not in AXES:
            raise ValueError(f"rate point {name}: axis must be one of {AXES}, got {self.axis!r}")
        for f in ("gyro_mean", "gyro_sem"):
            v = np.asarray(getattr(self, f), dtype=float)
            if v.shape != (3,) or not np.isfinite(v).all():
                raise ValueError(f"rate point {name}: {f} must be 3 finite numbers, got {v!r}")
            object.__setattr__(self, f, v)
        if not (self.gyro_sem > 0).all():
            raise ValueError(f"rate point {name}: gyro_sem must be > 0, got {self.gyro_sem}")
        if not math.isfinite(self.table_rate):
            raise ValueError(f"rate point {name}: table_rate is not finite")

    @property
    def name(self) -> str:
        return self.label or f"{self.axis}_{self.table_rate / DEG:+g}"


def rate_point(
    rec: Recording,
    *,
    axis: str | None = None,
    settle_s: float = 20.0,
    record_s: float | None = None,
) -> RatePoint:
    """Reduce one plateau Recording to a RatePoint.

    Parameters
    ----------
    rec : samples of one plateau with ``reference["table_rate"]`` (rad/s).
    axis : body axis on the table; default: the label's first field ("x_+100" -> "x").
    settle_s : time dropped at the start of the plateau, s (>= 20 s, docs/methods.md 2.4).
    record_s : length of the record window after the settle, s; default: to the end.

    Returns
    -------
    RatePoint with the window means; sem = sample std / sqrt(n), which assumes white
    noise over the window (true for MEMS gyros over 10 s; see static_bias otherwise).
    """
    where = rec.source or "recording"
    name = rec.label or where
    if "table_rate" not in rec.reference:
        raise ValueError(
            f"rate point {name} ({where}): no 'table_rate' reference channel; "
            f"have {sorted(rec.reference)}"
        )
    if axis is None:
        axis = (rec.label or "").split("_")[0]
        if axis not in AXES:
            raise ValueError(
                f"rate point ({where}): cannot tell the table axis from label {rec.label!r}; "
                "expected '<x|y|z>_<rate>' or pass axis="
            )
    start = rec.t[0] + settle_s
    end = np.inf if record_s is None else start + record_s
    keep = (rec.t >= start) & (rec.t < end)
    n = int(keep.sum())
    if n < 10:
        raise ValueError(
            f"rate point {name} ({where}): only {n} samples after a {settle_s} s settle "
            f"(plateau is {rec.duration:.1f} s long); need >= 10"
        )
    g = rec.gyr[keep]
    return RatePoint(
        axis=axis,
        table_rate=float(rec.reference["table_rate"][keep].mean()),
        gyro_mean=g.mean(axis=0),
        gyro_sem=g.std(axis=0, ddof=1) / math.sqrt(n),
        n=n,
        label=rec.label,
    )


def rate_points(recordings: list[Recording], **kwargs) -> list[RatePoint]:
    """`rate_point` of each recording (same keyword arguments)."""
    return [rate_point(r, **kwargs) for r in recordings]


def _wls(A: np.ndarray, y: np.ndarray, sem: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Weighted least squares: (x, covariance, chi^2) of y = A x with std `sem`."""
    Aw, yw = A / sem[:, None], y / sem
    x, *_ = np.linalg.lstsq(Aw, yw, rcond=None)
    cov = np.linalg.inv(Aw.T @ Aw)
    return x, cov, float(np.sum((yw - Aw @ x) ** 2))


def design_matrix(points: list[RatePoint], excited: list[int]) -> np.ndarray:
    """(P, 1 + J) design of one channel: a 1 for the bias, then the table rate on each
    excited axis j (0 for points about other axes)."""
    W = _rates(points)
    return np.column_stack([np.ones(len(points)), W[:, excited]])


def _rates(points: list[RatePoint]) -> np.ndarray:
    W = np.zeros((len(points), 3))
    for p, pt in enumerate(points):
        W[p, AXES.index(pt.axis)] = pt.table_rate
    return W


GYRO_BIAS_MODES = ("joint", "static")


def solve_rate_table(
    points: list[RatePoint],
    *,
    full_scale: float | None = None,
    gyro_bias: str = "joint",
    static_bias: tuple[np.ndarray, np.ndarray] | None = None,
) -> Calibration:
    """Least-squares gyro bias, scale factors and misalignments from rate points.

    Parameters
    ----------
    points : rate points, about one or more axes, both directions, with 0-rate points.
    full_scale : input full scale, rad/s, for the nonlinearity; default: the largest
        |table rate| about each axis.
    gyro_bias : "joint" (default): the bias is fitted with the scale factors from all
        points. "static": the procedure's model (docs/methods.md 2.4, 2.5): the bias is fixed
        from the static run, and the moving points give the scale factors and
        misalignments alone, ``mean_i - w_i - b_i = sum_j M_ij w_j``; the bias's
        uncertainty is propagated into them (with its covariance).
    static_bias : (value (3,), standard uncertainty (3,)) in rad/s of a separate static
        run (procedure static_bias); None: the weighted mean of the 0-rate points.

    Returns
    -------
    Calibration "rate_table" with gyr.bias.*, gyr.scale.j and gyr.misalign.ij for
    every excited axis j (standard uncertainties from the sems), residuals per rate
    point, and in `info`: chi2/dof per channel, bias consistency at 0 rate,
    nonlinearity (ppm of full scale) and asymmetry (ppm) per excited axis, gyro_bias.
    """
    if gyro_bias not in GYRO_BIAS_MODES:
        raise ValueError(
            f"rate table: gyro_bias must be one of {GYRO_BIAS_MODES}, got {gyro_bias!r}"
        )
    if not points:
        raise ValueError("rate table: no rate points")
    W = _rates(points)
    Y = np.array([p.gyro_mean for p in points])
    S = np.array([p.gyro_sem for p in points])
    excited = [j for j in range(3) if (np.abs(W[:, j]) > ZERO_RATE).any()]
    if not excited:
        raise ValueError("rate table: every rate point is at 0 rad/s; nothing to scale")
    A = design_matrix(points, excited)
    if len(points) <= A.shape[1] or np.linalg.matrix_rank(A) < A.shape[1]:
        raise ValueError(
            f"rate table: {len(points)} points cannot determine a bias and {len(excited)} "
            "scale column(s); need at least one more point than unknowns, with two distinct "
            "rates about each axis"
        )
    cal = Calibration(procedure="rate_table", gravity=STANDARD_GRAVITY)
    if gyro_bias == "static":
        model, chi2_dof = _fit_fixed_bias(cal, W, Y, S, excited, _static_bias(W, Y, S, static_bias))
    else:
        model, chi2_dof = _fit_joint(cal, A, W, Y, S, excited)
    for p, pt in enumerate(points):
        resid = Y[p] - model[p]
        cal.residuals.append(
            SegmentResidual(
                segment=pt.name,
                sensor="gyr",
                mean=tuple(float(v) for v in resid),
                std=tuple(float(v) for v in pt.gyro_sem * math.sqrt(pt.n)),
                n=pt.n,
            )
        )
    cal.info["gyro_bias"] = gyro_bias
    cal.info["chi2_dof"] = chi2_dof
    cal.info["excited_axes"] = [AXES[j] for j in excited]
    cal.info["zero_rate_bias"] = _zero_rate_consistency(points, W, Y, S, excited, cal)
    M = cal.matrix("gyr")
    nonlin, asym = {}, {}
    for j in excited:
        a = AXES[j]
        on = np.array([pt.axis == a for pt in points])
        fs = full_scale if full_scale is not None else float(np.abs(W[on, j]).max())
        nonlin[a] = _nonlinearity(W[on, j], Y[on, j] - model[on, j], fs, M[j, j])
        asym[a] = _asymmetry(W[on, j], Y[on, j], S[on, j])
    cal.info["nonlinearity"] = nonlin
    cal.info["asymmetry"] = asym
    return cal


def _column_names(i: int, excited: list[int]) -> list[str]:
    a = AXES[i]
    return [f"gyr.scale.{a}" if i == j else f"gyr.misalign.{a}{AXES[j]}" for j in excited]


def _chi2_warning(cal: Calibration, axis: str, chi2: float, dof: int) -> None:
    p_value = chi2_sf(chi2, dof)
    if p_value < 1e-3:
        cal.warnings.append(
            f"gyr {axis}: rate-point residuals too large for the linear model "
            f"(chi2/dof = {chi2 / dof:.2f}, p = {p_value:.1e}): nonlinearity, table error "
            "or correlated noise"
        )


def _fit_joint(cal, A, W, Y, S, excited) -> tuple[np.ndarray, list[float]]:
    """Bias and scale column fitted together per output channel; (model (P, 3), chi2/dof)."""
    model = np.zeros_like(Y)
    chi2_dof = []
    for i, a in enumerate(AXES):
        x, cov, chi2 = _wls(A, Y[:, i] - W[:, i], S[:, i])
        u = np.sqrt(np.diag(cov))
        cal.add(f"gyr.bias.{a}", x[0], u[0])
        for k, name in enumerate(_column_names(i, excited)):
            cal.add(name, x[k + 1], u[k + 1])
        model[:, i] = A @ x + W[:, i]
        dof = len(Y) - A.shape[1]
        chi2_dof.append(chi2 / dof)
        _chi2_warning(cal, a, chi2, dof)
    return model, chi2_dof


def _static_bias(W, Y, S, given) -> tuple[np.ndarray, np.ndarray]:
    """The fixed bias (3,) and its standard uncertainty (3,), rad/s: as given, else the
    weighted mean of the 0-rate points."""
    if given is not None:
        value, u = (np.asarray(v, dtype=float) for v in given)
        if value.shape != (3,) or u.shape != (3,) or not (u >= 0).all():
            raise ValueError("rate table: static_bias must be (3,) values and (3,) stds >= 0")
        return value, u
    zero = np.abs(W).max(axis=1) <= ZERO_RATE
    if not zero.any():
        raise ValueError(
            "rate table: gyro_bias = 'static' needs the static run: a 0-rate point, or the "
            "bias of a static-bias run in settings (static_bias_dps)"
        )
    w = 1.0 / S[zero] ** 2
    return (w * Y[zero]).sum(axis=0) / w.sum(axis=0), 1.0 / np.sqrt(w.sum(axis=0))


def _fit_fixed_bias(cal, W, Y, S, excited, bias) -> tuple[np.ndarray, list[float]]:
    """Scale column per channel from the moving points with the bias fixed; the bias's
    uncertainty u_b enters as cov(x) += g g^T u_b^2, cov(b, x) = g u_b^2, with
    g = dx/db = -(A^T A)^-1 A^T 1 (weighted)."""
    b, u_b = bias
    moving = np.abs(W).max(axis=1) > ZERO_RATE
    A = W[moving][:, excited]
    if moving.sum() <= A.shape[1] - 1 or np.linalg.matrix_rank(A) < A.shape[1]:
        raise ValueError("rate table: too few moving points for the scale factors")
    model = np.zeros_like(Y)
    chi2_dof = []
    for i, a in enumerate(AXES):
        sem = S[moving, i]
        x, cov_y, chi2 = _wls(A, Y[moving, i] - W[moving, i] - b[i], sem)
        g = -cov_y @ (A / sem[:, None] ** 2).sum(axis=0)
        cov = np.zeros((len(x) + 1,) * 2)
        cov[0, 0] = u_b[i] ** 2
        cov[0, 1:] = cov[1:, 0] = g * u_b[i] ** 2
        cov[1:, 1:] = cov_y + np.outer(g, g) * u_b[i] ** 2
        names = [f"gyr.bias.{a}", *_column_names(i, excited)]
        cal.add_fit(names, dict(zip(names, [b[i], *x], strict=True)), cov)
        model[:, i] = b[i] + W[:, excited] @ x + W[:, i]
        dof = int(moving.sum()) - A.shape[1]
        chi2_dof.append(chi2 / dof if dof > 0 else float("nan"))
        if dof > 0:
            _chi2_warning(cal, a, chi2, dof)
    return model, chi2_dof


def _zero_rate_consistency(points, W, Y, S, excited, cal) -> dict | None:
    """0-rate bias (weighted mean) against the intercept fitted from the non-zero points."""
    zero = np.abs(W).max(axis=1) <= ZERO_RATE
    if not zero.any():
        return None
    w = 1.0 / S[zero] ** 2
    b0 = (w * Y[zero]).sum(axis=0) / w.sum(axis=0)
    u0 = 1.0 / np.sqrt(w.sum(axis=0))
    moving = [p for p, z in zip(points, zero, strict=True) if not z]
    A = design_matrix(moving, excited)
    if len(moving) < A.shape[1] or np.linalg.matrix_rank(A) < A.shape[1]:
        return {"bias_zero_rate": b0.tolist(), "u_zero_rate": u0.tolist()}
    b1, u1 = np.zeros(3), np.zeros(3)
    for i in range(3):
        x, cov, _ = _wls(A, Y[~zero, i] - W[~zero, i], S[~zero, i])
        b1[i], u1[i] = x[0], math.sqrt(cov[0, 0])
    diff = b0 - b1
    z = diff / np.sqrt(u0**2 + u1**2)
    for i, a in enumerate(AXES):
        if abs(z[i]) > 4.0:
            cal.warnings.append(
                f"gyr {a}: bias at 0 rate ({b0[i]:.3e} rad/s) differs from the bias fitted from "
                f"the moving points ({b1[i]:.3e} rad/s) by {z[i]:.1f} standard uncertainties"
            )
    return {
        "bias_zero_rate": b0.tolist(),
        "u_zero_rate": u0.tolist(),
        "bias_moving": b1.tolist(),
        "u_moving": u1.tolist(),
        "difference_sigma": z.tolist(),
    }


def _nonlinearity(rates: np.ndarray, resid: np.ndarray, full_scale: float, m_jj: float) -> dict:
    """Largest on-axis residual over the full-scale output, ppm, plus per-point scales."""
    fs_out = (1.0 + m_jj) * full_scale
    moving = np.abs(rates) > ZERO_RATE
    # per-point scale factor deviation from the fitted one: residual / rate
    return {
        "ppm_of_full_scale": float(np.abs(resid).max() / fs_out * 1e6),
        "full_scale": full_scale,
        "rates": rates.tolist(),
        "residuals": resid.tolist(),
        "scale_deviation_ppm": (resid[moving] / rates[moving] / (1.0 + m_jj) * 1e6).tolist(),
    }


def _asymmetry(rates: np.ndarray, y: np.ndarray, sem: np.ndarray) -> dict | None:
    """K+ and K- with a shared bias; asymmetry (K+ - K-) / mean(K+, K-) in ppm."""
    pos, neg = rates > ZERO_RATE, rates < -ZERO_RATE
    if not pos.any() or not neg.any() or rates.size < 4:
        return None
    A = np.column_stack([np.ones_like(rates), np.where(pos, rates, 0.0), np.where(neg, rates, 0.0)])
    x, cov, _ = _wls(A, y, sem)
    kp, kn = x[1], x[2]
    k = 0.5 * (kp + kn)
    asym = (kp - kn) / k
    # gradient of (kp - kn) / ((kp + kn) / 2) with respect to (b, kp, kn)
    g = np.array([0.0, 1.0 / k - asym / (2.0 * k), -1.0 / k - asym / (2.0 * k)])
    return {
        "ppm": float(asym * 1e6),
        "u_ppm": float(math.sqrt(g @ cov @ g) * 1e6),
        "scale_positive": float(kp),
        "scale_negative": float(kn),
    }
