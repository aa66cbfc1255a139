"""Centrifuge procedure, the science: the high-g error model and the geometry.

Mountings (MOUNTS), the candidate terms of each axis's model and their canonical
names, the run's steps (CentrifugeStep) and settings, whole-revolution means, the
centripetal input from radius and rate, the effective radius, the fitted model
(AxisModel, CentrifugeModel) and `compensate`. The fit itself: calib_core.solvers.centrifuge.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from calib_core.earth import EARTH_RATE
from calib_core.params import AXES, AXIS_INDEX
from calib_core.recording import Recording
from calib_core.significance import CONST, STEERING, T_TESTS, OlsFit, Reduction
from calib_core.units import STANDARD_GRAVITY

if TYPE_CHECKING:
    from calib_core.solvers.centrifuge_plan import ZeroShift

# Sensor axes in the mounting frame (r, t, u): row i of P is sensor axis i.
# Positions keep the frame right-handed (for "-": axis = -r, the next = -t).
MOUNTS: dict[str, np.ndarray] = {
    "x+": np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float),
    "x-": np.array([[-1, 0, 0], [0, -1, 0], [0, 0, 1]], dtype=float),
    "y+": np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], dtype=float),
    "y-": np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=float),
    "z+": np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]], dtype=float),
    "z-": np.array([[0, -1, 0], [0, 0, 1], [-1, 0, 0]], dtype=float),
}
ZERO_POSITIONS_DEG = (0.0, 90.0, 180.0, 270.0)
STEP_KINDS = ("zero", "zero_after", "1g", "step")
# docs/methods.md 3.6: accelerometer residual std <= 0.002 g. A zero that moved by more
# than the model may leave unexplained is a run to repeat.
DEFAULT_ZERO_SHIFT_LIMIT = 0.002 * STANDARD_GRAVITY
# The paper's reduction: the model F test, then the t tests (docs/methods.md 2.8); on
# simulated runs it keeps the same terms as steering by t alone (docs/centrifuge.md).
DEFAULT_STEER = "F-then-t"
# Where the effective radius comes from: the near-1 g runs (the paper's) or all records
# jointly with every axis's model (docs/methods.md 2.8).
RADIUS_FROM = ("near_1g", "all_records")

_TERM = re.compile(r"^a_([xyz])(?:\^([23]))?(?:\*a_([xyz]))?$")


def full_terms(axis: str) -> tuple[str, ...]:
    """The 10 candidate regressors of the full high-g model of `axis` (constant not included)."""
    i = AXIS_INDEX[axis]
    j, k = AXES[(i + 1) % 3], AXES[(i + 2) % 3]
    # products named in axis order: "a_x*a_z", never "a_z*a_x"
    pairs = [sorted(p, key=AXIS_INDEX.__getitem__) for p in ((axis, j), (axis, k), (j, k))]
    return (
        f"a_{axis}",
        f"a_{axis}^2",
        f"a_{axis}^3",
        f"a_{j}",
        f"a_{k}",
        f"a_{j}^2",
        f"a_{k}^2",
        *(f"a_{p}*a_{q}" for p, q in pairs),
    )


def term_values(f: np.ndarray, terms: Sequence[str]) -> np.ndarray:
    """Regressor columns for the given term names.

    Parameters
    ----------
    f : (N, 3) input specific force in the sensor axes, m/s^2.
    terms : names ``"const"``, ``"a_x"``, ``"a_x^2"``, ``"a_x^3"``, ``"a_x*a_y"``.

    Returns
    -------
    (N, len(terms)) float.
    """
    f = np.atleast_2d(np.asarray(f, dtype=float))
    cols = []
    for name in terms:
        if name == CONST:
            cols.append(np.ones(f.shape[0]))
            continue
        m = _TERM.match(name)
        if not m or (m[2] and m[3]):
            raise ValueError(
                f"unknown high-g term {name!r}; expected const, a_x, a_x^2, a_x^3 or a_x*a_y"
            )
        col = f[:, AXIS_INDEX[m[1]]] ** (int(m[2]) if m[2] else 1)
        if m[3]:
            col = col * f[:, AXIS_INDEX[m[3]]]
        cols.append(col)
    return np.column_stack(cols) if cols else np.empty((f.shape[0], 0))


def canonical_name(axis: str, term: str) -> str:
    """Canonical parameter name (calib_core.params) of `term` in the model of `axis`.

    const -> acc.bias.x, a_x -> acc.scale.x, a_x^2 -> acc.k2.x, a_x^3 -> acc.k3.x,
    a_y -> acc.misalign.xy, a_y^2 -> acc.k2.xy, a_y*a_z -> acc.kp.x_yz.
    """
    if term == CONST:
        return f"acc.bias.{axis}"
    m = _TERM.match(term)
    if not m or (m[2] and m[3]) or (m[1] != axis and m[2] == "3"):
        raise ValueError(f"term {term!r} has no canonical name in the model of axis {axis!r}")
    if m[3]:
        return f"acc.kp.{axis}_{m[1]}{m[3]}"
    if m[1] == axis:
        return {None: f"acc.scale.{axis}", "2": f"acc.k2.{axis}", "3": f"acc.k3.{axis}"}[m[2]]
    return f"acc.k2.{axis}{m[1]}" if m[2] else f"acc.misalign.{axis}{m[1]}"


@dataclass(frozen=True, eq=False)
class CentrifugeStep:
    """One record of a centrifuge run.

    mount : one of `MOUNTS` ("x+", ..., "z-").
    kind : "zero" (static at `table_position_deg`, before the run), "zero_after" (the
        same after the run), "1g" (the radius run) or "step".
    recording : samples with reference channels ``"table_angle"`` (rad,
        unwrapped or wrapped) and ``"table_rate"`` (rad/s, signed about up).
    nominal_g : nominal input in g (0 for zero records), for labels and reports.
    """

    mount: str
    kind: str
    recording: Recording
    nominal_g: float = 0.0
    table_position_deg: float | None = None

    def __post_init__(self) -> None:
        where = self.recording.source or f"{self.mount} {self.kind} {self.nominal_g:g} g"
        if self.mount not in MOUNTS:
            raise ValueError(f"{where}: mount must be one of {list(MOUNTS)}, got {self.mount!r}")
        if self.kind not in STEP_KINDS:
            raise ValueError(f"{where}: kind must be one of {STEP_KINDS}, got {self.kind!r}")
        for ch in ("table_angle", "table_rate"):
            if ch not in self.recording.reference:
                raise ValueError(f"{where}: reference channel {ch!r} is missing")
        if self.kind in ("zero", "zero_after") and self.table_position_deg is None:
            raise ValueError(f"{where}: a zero record needs table_position_deg")


@dataclass(frozen=True)
class CentrifugeSettings:
    """Settings of `solve_centrifuge`.

    latitude_deg : site latitude (Earth rate's vertical component).
    gravity : local gravity, m/s^2 (the vertical input).
    alpha : significance level of the t and F tests.
    t_test : "two-sided" (default) or "one-sided" (the paper's: 1.676 at its
        49 degrees of freedom instead of 2.010).
    steer : how the stepwise reduction decides: "F-then-t" (default, the
        paper's: the weakest term goes while the model fails its F test, then
        while its t test fails), "t" (every kept term passes its t test) or "F"
        (remove while the model F grows and passes;
        `calib_core.significance.stepwise_reduce`).
    scale_1g : per axis, the 1 g scale error K - 1 from a static calibration
        (the centrifuge cannot separate it from the radius); absent = 0.
    common_radius : one effective radius for all positions (inverse-variance
        mean of the six estimates; right when the proof masses sit within
        millimetres) instead of one per position.
    iterations : radius / phi_h / model passes; later passes remove the model's
        even-order terms at 1 g from the radius estimate and refine phi_h.
    scale_instability : relative scale-factor instability from step to step
        (one value or one per axis), which makes a step's error grow with its
        input; None (default) estimates it per axis from the full model's
        residuals (`step_weights`). The steps are weighted by 1 / variance.
    zero_shift_limit : allowed change of a position's zero output between the
        records before and after its run, m/s^2 (default 0.002 g).
    radius_from : "all_records" (default): the radius refined with every axis's model
        over all records (each axis's linear term held at its `scale_1g`), and the
        near-1 g runs and zero outputs fitted as rows of each axis's model besides the
        high-g steps; "near_1g" (the paper's): the effective radius from the near-1 g
        runs and zero records alone.
    """

    latitude_deg: float
    gravity: float = STANDARD_GRAVITY
    alpha: float = 0.05
    t_test: str = "two-sided"
    steer: str = DEFAULT_STEER
    scale_1g: Mapping[str, float] = field(default_factory=dict)
    common_radius: bool = True
    iterations: int = 4
    scale_instability: float | Mapping[str, float] | None = None
    zero_shift_limit: float = DEFAULT_ZERO_SHIFT_LIMIT
    radius_from: str = "all_records"

    def __post_init__(self) -> None:
        if self.radius_from not in RADIUS_FROM:
            raise ValueError(
                f"radius_from must be one of {list(RADIUS_FROM)}, got {self.radius_from!r}"
            )
        if self.t_test not in T_TESTS:
            raise ValueError(f"t_test must be one of {list(T_TESTS)}, got {self.t_test!r}")
        if self.steer not in STEERING:
            raise ValueError(f"steer must be one of {list(STEERING)}, got {self.steer!r}")
        if not (math.isfinite(self.zero_shift_limit) and self.zero_shift_limit > 0.0):
            raise ValueError(
                f"zero_shift_limit must be a positive number (m/s^2), got {self.zero_shift_limit}"
            )


@dataclass(frozen=True)
class Estimate:
    """A value with its standard uncertainty (1 sigma)."""

    value: float
    std: float


@dataclass(frozen=True)
class RevolutionMean:
    """Whole-revolution average of one record: mean (3,) outputs and mean table rate."""

    acc: np.ndarray
    acc_std: np.ndarray  # (3,) standard error of the mean, white-noise assumption
    rate: float
    rate_std: float
    revolutions: int
    samples: int


def whole_revolution_mean(recording: Recording) -> RevolutionMean:
    """Average a rotating record over whole revolutions of the table angle only.

    Samples from the first one up to (not including) the first sample whose
    accumulated table angle reaches the last whole revolution are averaged;
    anything periodic in the table angle (axis tilt, horizontal Earth-rate
    Coriolis) then averages out.
    """
    angle = np.unwrap(np.asarray(recording.reference["table_angle"], dtype=float))
    turned = np.abs(angle - angle[0])
    revolutions = int(np.floor(turned[-1] / (2.0 * math.pi)))
    if revolutions < 1:
        raise ValueError(
            f"{recording.source or recording.label}: the table turned "
            f"{math.degrees(turned[-1]):.1f} deg, need at least one whole revolution"
        )
    use = turned < revolutions * 2.0 * math.pi
    n = int(use.sum())
    acc = recording.acc[use]
    rate = np.asarray(recording.reference["table_rate"], dtype=float)[use]
    return RevolutionMean(
        acc=acc.mean(axis=0),
        acc_std=acc.std(axis=0, ddof=1) / math.sqrt(n),
        rate=float(rate.mean()),
        rate_std=float(rate.std(ddof=1) / math.sqrt(n)),
        revolutions=revolutions,
        samples=n,
    )


def zero_output(records: Sequence[CentrifugeStep]) -> tuple[np.ndarray, np.ndarray]:
    """Zero output of one mounting position from its four static table positions.

    Returns
    -------
    (mean (3,), standard error (3,)), m/s^2: the average of the four position
    means, in which a table-axis tilt cancels.
    """
    positions = sorted(float(r.table_position_deg) % 360.0 for r in records)
    if len(positions) != 4 or not np.allclose(positions, ZERO_POSITIONS_DEG, atol=1.0):
        where = records[0].mount if records else "?"
        raise ValueError(
            f"mount {where}: zero output needs static records at table positions "
            f"{ZERO_POSITIONS_DEG} deg, got {positions}"
        )
    means = np.array([r.recording.acc.mean(axis=0) for r in records])
    sems = np.array(
        [r.recording.acc.std(axis=0, ddof=1) / math.sqrt(len(r.recording)) for r in records]
    )
    return means.mean(axis=0), np.sqrt((sems**2).sum(axis=0)) / 4.0


def vertical_earth_rate(latitude_deg: float) -> float:
    """Up component of Earth rate, rad/s (positive in the northern hemisphere)."""
    return EARTH_RATE * math.sin(math.radians(latitude_deg))


def centripetal_input(radius: float, rate: float, omega_v: float) -> float:
    """Specific force towards the table axis, R w (w + 2 Omega_V), m/s^2.

    `rate` is signed about the up axis; the Coriolis term of Earth rate adds
    when the table turns with the Earth and subtracts when against it.
    """
    return radius * rate * (rate + 2.0 * omega_v)


def effective_radius(
    delta: float, delta_std: float, rate: float, rate_std: float, omega_v: float
) -> Estimate:
    """Effective radius from the radial input change at the near-1 g run.

    Parameters
    ----------
    delta, delta_std : a_radial = E_rot - E_static corrected to input units, m/s^2.
    rate, rate_std : mean signed table rate and its standard error, rad/s.
    omega_v : vertical Earth-rate component, rad/s.

    Returns
    -------
    Estimate, m: R = delta / (w0 (w0 + 2 Omega_V)), uncertainty from delta and w0.
    """
    denom = rate * (rate + 2.0 * omega_v)
    if denom <= 0.0:
        raise ValueError(f"near-1 g run: table rate {rate} rad/s gives no centripetal input")
    R = delta / denom
    d_rate = (2.0 * rate + 2.0 * omega_v) / denom  # d ln(denom) / d rate
    return Estimate(R, abs(R) * math.hypot(delta_std / delta, d_rate * rate_std))


@dataclass(frozen=True, eq=False)
class AxisModel:
    """The reduced high-g model of one accelerometer axis (error = output - input).

    reduction : the stepwise reduction; its fits also hold the nuisance columns.
    nuisance : names of the fitted columns that are not model terms: the
        horizontal-misalignment corrections ``"phi:<mount>"`` of the positions
        where this axis is tangential (kept in every fit, never tested).
    not_identifiable : candidate terms of the full model that these mountings
        cannot separate from other terms, the radius or phi_h (`identifiable_terms`);
        they were not fitted.
    scale_instability : relative step-to-step scale instability used in the
        weights (estimated or given).
    radius_cov : (p, p) over the final fit's columns (`fit.names`), the covariance the
        effective radius's uncertainty adds to the coefficients (the radius comes from
        the near-1 g runs and zero records, not from the fitted steps); None: none.
    """

    axis: str
    reduction: Reduction
    nuisance: tuple[str, ...] = ()
    not_identifiable: tuple[str, ...] = ()
    scale_instability: float = 0.0
    radius_cov: np.ndarray | None = None

    @property
    def fit(self) -> OlsFit:
        return self.reduction.final

    @property
    def _model_columns(self) -> list[int]:
        return [j for j, n in enumerate(self.fit.names) if n not in self.nuisance]

    @property
    def terms(self) -> tuple[str, ...]:
        """Kept model terms (nuisance columns excluded), e.g. ``("const", "a_x", "a_x^2")``."""
        return tuple(self.fit.names[j] for j in self._model_columns)

    @property
    def coef(self) -> np.ndarray:
        """(len(terms),) coefficients of `terms`, m/s^2 per unit of each term."""
        return self.fit.coef[self._model_columns]

    @property
    def cov(self) -> np.ndarray:
        """(len(terms), len(terms)) covariance of `coef`.

        The kept terms' block of the full model's covariance (every identifiable
        candidate, the model the reduction chose from), plus the radius's
        (`radius_cov`). The reduced fit's own covariance is conditional on a choice of
        terms made on the same data: a null term the tests admit (some 30 % of runs
        with 7 candidates a axis at alpha 0.05) is one the noise happened to favour,
        and it moves the correlated terms, the bias first, by 2-3 of their reduced-fit
        uncertainties. The full model holds the truth whatever the choice.
        """
        full = self.reduction.full
        idx = [full.names.index(t) for t in self.terms]
        out = full.cov[np.ix_(idx, idx)]
        if self.radius_cov is not None:
            cols = self._model_columns
            out = out + self.radius_cov[np.ix_(cols, cols)]
        return out

    @property
    def std(self) -> np.ndarray:
        """(len(terms),) standard uncertainties of `coef` (`cov`)."""
        return np.sqrt(np.diag(self.cov))

    def error(self, f: np.ndarray) -> np.ndarray:
        """(N, 3) sensor-axis inputs, m/s^2 -> (N,) modelled error of this axis, m/s^2."""
        return term_values(f, self.terms) @ self.coef


@dataclass(frozen=True, eq=False)
class CentrifugeModel:
    """Result of `solve_centrifuge`.

    axes : per axis the reduced model with F, F_crit, R^2, t values and the removal sequence.
    radius : per mounting position the effective radius used, m.
    radius_raw : per position the estimate from its own near-1 g run, m.
    phi_h : per position the horizontal misalignment, rad, refined over all
        steps together with the model of the tangential axis (used for the inputs).
    phi_h_1g : per position phi_h = atan(a_t / a_r) from the near-1 g run alone.
    zero : per position the zero output (3,), m/s^2.
    zero_shift : per position with zero records after the run, the change of the
        zero output and its check (`calib_core.solvers.centrifuge_plan.ZeroShift`).
    """

    axes: dict[str, AxisModel]
    radius: dict[str, Estimate]
    radius_raw: dict[str, Estimate]
    phi_h: dict[str, Estimate]
    phi_h_1g: dict[str, Estimate]
    zero: dict[str, np.ndarray]
    gravity: float
    omega_v: float
    zero_shift: dict[str, ZeroShift] = field(default_factory=dict)

    def error(self, f: np.ndarray) -> np.ndarray:
        """(N, 3) inputs -> (N, 3) modelled errors, m/s^2."""
        return np.column_stack([self.axes[a].error(f) for a in AXES])

    def input_force(self, mount: str, rate: np.ndarray | float) -> np.ndarray:
        """Reference input (N, 3) in sensor axes for table rate(s) at a mounting position."""
        a = centripetal_input(self.radius[mount].value, np.asarray(rate, dtype=float), self.omega_v)
        phi = self.phi_h[mount].value
        f_mount = np.column_stack(
            np.broadcast_arrays(a * math.cos(phi), a * math.sin(phi), self.gravity)
        )
        return f_mount @ MOUNTS[mount].T

    def parameters(self) -> dict[str, Estimate]:
        """Kept terms by canonical name (acc.bias.x, acc.scale.x, acc.k2.xy, ...).

        Each uncertainty includes the effective radius's (`AxisModel.radius_cov`): a
        relative radius error moves the radial inputs, hence the scale one for one,
        and through the scale the bias, which must then explain the up axis's g.
        """
        out = {}
        for axis, m in self.axes.items():
            for term, c, s in zip(m.terms, m.coef, m.std, strict=True):
                out[canonical_name(axis, term)] = Estimate(float(c), float(s))
        return out


def compensate(model: CentrifugeModel, readings: np.ndarray, iterations: int = 8) -> np.ndarray:
    """Invert the high-g model: readings E (N, 3) -> input estimates f (N, 3), m/s^2.

    Solves E = f + e(f) by fixed-point iteration f <- E - e(f); the model's
    slope is ~1e-3, so each pass gains about three digits.
    """
    E = np.atleast_2d(np.asarray(readings, dtype=float))
    if E.shape[1:] != (3,):
        raise ValueError(f"readings must have shape (N, 3), got {E.shape}")
    f = E.copy()
    for _ in range(iterations):
        f = E - model.error(f)
    return f
