"""Uncertainty budget per parameter (GUM, JCGM 100) and its Monte Carlo check (JCGM 101).

Science only (numpy/scipy). A budget combines the Type A standard uncertainty of the fit with
Type B inputs of the reference (local gravity, cube/fixture angles, table rate and angle, ...),
each with its distribution. Sensitivity coefficients are computed through the solver by central
finite differences of the solve with respect to each Type B input. The combined standard
uncertainty, the Welch-Satterthwaite effective degrees of freedom, the coverage factor for about
95 % from Student's t and the expanded uncertainty U follow. A run without equipment knowledge
gets a budget labelled Type A only (``Budget.type_a_only``), never a silently smaller U.

The Monte Carlo check draws every input from its stated distribution, pushes each draw through
the same solver and takes the probabilistically symmetric 95 % interval (numpy sampling).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib_core.distributions import norm_ppf, t_ppf

# Divisor from a stated half-width a (or expanded U at k for "normal") to a standard uncertainty.
_DIVISORS = {
    "rectangular": math.sqrt(3.0), "triangular": math.sqrt(6.0), "u-shaped": math.sqrt(2.0),
}
DISTRIBUTIONS = ("normal", *_DIVISORS)

Solve = Callable[[Mapping[str, float]], Mapping[str, float]]


@dataclass(frozen=True)
class InputQuantity:
    """A Type B input of the measurement model.

    Attributes
    ----------
    name : source name, e.g. "gravity" or "cube.x_up.tilt_a".
    value : its estimate (SI).
    half_width : half-width a of a rectangular/triangular/u-shaped distribution, or the
        expanded uncertainty at coverage factor `k` of a normal one (SI).
    distribution : one of DISTRIBUTIONS.
    k : coverage factor of `half_width` when the distribution is normal (certificate's k).
    dof : degrees of freedom of the standard uncertainty (inf: known exactly).
    unit : unit of value and half_width.
    """

    name: str
    value: float
    half_width: float
    distribution: str = "rectangular"
    k: float = 2.0
    dof: float = math.inf
    unit: str = ""

    def __post_init__(self) -> None:
        if self.distribution not in DISTRIBUTIONS:
            raise ValueError(
                f"input {self.name!r}: distribution {self.distribution!r}, "
                f"expected one of {DISTRIBUTIONS}"
            )
        if not (self.half_width >= 0 and math.isfinite(self.half_width)):
            raise ValueError(f"input {self.name!r}: half-width must be >= 0, got {self.half_width}")

    @property
    def std(self) -> float:
        """Standard uncertainty u(x) (SI)."""
        if self.distribution == "normal":
            return self.half_width / self.k
        return self.half_width / _DIVISORS[self.distribution]

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n,) draws from the stated distribution."""
        a = self.half_width
        if self.distribution == "normal":
            return self.value + self.std * rng.standard_normal(n)
        if self.distribution == "rectangular":
            return self.value + rng.uniform(-a, a, n)
        if self.distribution == "triangular":
            return self.value + rng.triangular(-a, 0.0, a, n)
        return self.value + a * np.sin(rng.uniform(-np.pi, np.pi, n))  # u-shaped (arcsine)


@dataclass(frozen=True)
class Contribution:
    """One row of a budget table: u_i(y) = |c_i| u(x_i)."""

    source: str
    kind: str  # "A" or "B"
    distribution: str
    std_input: float
    sensitivity: float
    contribution: float
    dof: float
    unit: str = ""

    def to_dict(self) -> dict[str, Any]:
        """The row as JSON-friendly values (inf degrees of freedom as None)."""
        d = dict(self.__dict__)
        d["dof"] = None if math.isinf(self.dof) else self.dof
        return d


@dataclass(frozen=True)
class Budget:
    """Uncertainty budget of one parameter: rows, u_c, nu_eff, k (about 95 %), U = k u_c."""

    parameter: str
    value: float
    unit: str
    rows: tuple[Contribution, ...]
    uc: float
    nu_eff: float
    k: float
    U: float
    coverage: float = 0.95
    type_a_only: bool = False
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def label(self) -> str:
        """"Type A only (equipment unknown)" or "Type A + Type B"."""
        return "Type A only (equipment unknown)" if self.type_a_only else "Type A + Type B"

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly document of the budget."""
        return {
            "parameter": self.parameter, "value": self.value, "unit": self.unit,
            "rows": [r.to_dict() for r in self.rows], "uc": self.uc,
            "nu_eff": None if math.isinf(self.nu_eff) else self.nu_eff,
            "k": self.k, "U": self.U, "coverage": self.coverage,
            "type_a_only": self.type_a_only, "label": self.label, "notes": list(self.notes),
        }


def coverage_factor(nu_eff: float, coverage: float = 0.95) -> float:
    """k from Student's t at nu_eff degrees of freedom (normal when nu_eff is infinite)."""
    q = 0.5 + coverage / 2.0
    if math.isinf(nu_eff):
        return norm_ppf(q)
    if nu_eff <= 0:
        raise ValueError(f"effective degrees of freedom must be > 0, got {nu_eff}")
    return t_ppf(q, nu_eff)


def welch_satterthwaite(contributions: Sequence[float], dofs: Sequence[float]) -> float:
    """nu_eff = u_c^4 / sum(u_i^4 / nu_i); inf when every nu_i is infinite (or u_c = 0)."""
    u = np.asarray(contributions, dtype=float)
    nu = np.asarray(dofs, dtype=float)
    uc2 = float(np.sum(u**2))
    finite = np.isfinite(nu)
    denom = float(np.sum(u[finite] ** 4 / nu[finite]))
    if denom == 0.0 or uc2 == 0.0:
        return math.inf
    return uc2**2 / denom


def combine(
    parameter: str, value: float, rows: Sequence[Contribution], unit: str = "",
    coverage: float = 0.95, type_a_only: bool = False, notes: Sequence[str] = (),
) -> Budget:
    """Combine uncorrelated budget rows into u_c, nu_eff, k and U."""
    u = [r.contribution for r in rows]
    uc = float(math.sqrt(sum(x * x for x in u)))
    nu = welch_satterthwaite(u, [r.dof for r in rows])
    k = coverage_factor(nu, coverage)
    return Budget(parameter, value, unit, tuple(rows), uc, nu, k, k * uc, coverage,
                  type_a_only, tuple(notes))


def sensitivities(
    solve: Solve, inputs: Sequence[InputQuantity], rel_step: float = 1.0
) -> dict[str, dict[str, float]]:
    """c[input][parameter] = d parameter / d input by central differences through `solve`.

    Parameters
    ----------
    solve : maps {input name: value} to {parameter name: estimate} (the solver with its data fixed).
    inputs : the Type B inputs; each is stepped by rel_step * u(x) (or 1e-9 |x| when u = 0).
    """
    nominal = {q.name: q.value for q in inputs}
    out: dict[str, dict[str, float]] = {}
    for q in inputs:
        h = rel_step * q.std or 1e-9 * max(abs(q.value), 1.0)
        hi = solve({**nominal, q.name: q.value + h})
        lo = solve({**nominal, q.name: q.value - h})
        out[q.name] = {p: (hi[p] - lo[p]) / (2.0 * h) for p in hi}
    return out


def budgets(
    solve: Solve, inputs: Sequence[InputQuantity], type_a: Mapping[str, tuple[float, float]],
    units: Mapping[str, str] | None = None, coverage: float = 0.95,
) -> dict[str, Budget]:
    """Budget of every parameter of `type_a` (name -> (std, dof)).

    With no `inputs` every budget is labelled Type A only (equipment unknown).
    """
    units = units or {}
    values = solve({q.name: q.value for q in inputs})
    sens = sensitivities(solve, inputs) if inputs else {}
    out: dict[str, Budget] = {}
    for name, (std_a, dof_a) in type_a.items():
        rows = [Contribution("fit (Type A)", "A", "normal", std_a, 1.0, std_a, dof_a,
                             units.get(name, ""))]
        for q in inputs:
            c = sens[q.name].get(name, 0.0)
            rows.append(Contribution(q.name, "B", q.distribution, q.std, c, abs(c) * q.std,
                                     q.dof, q.unit))
        notes = () if inputs else ("equipment unknown: Type B sources not evaluated",)
        out[name] = combine(name, float(values[name]), rows, units.get(name, ""), coverage,
                            type_a_only=not inputs, notes=notes)
    return out


def monte_carlo(
    solve: Solve, inputs: Sequence[InputQuantity], type_a: Mapping[str, tuple[float, float]],
    n: int = 2000, rng: np.random.Generator | None = None, coverage: float = 0.95,
) -> dict[str, tuple[float, float, float]]:
    """JCGM 101 check: name -> (mean, lower, upper) of the symmetric coverage interval.

    Each draw pushes the Type B inputs through `solve`; the Type A part is added as a scaled
    Student-t draw (normal when its dof is infinite) of the fit's standard uncertainty.
    """
    rng = rng or np.random.default_rng(0)
    draws = {q.name: q.sample(rng, n) for q in inputs}
    names = list(type_a)
    ys = np.empty((n, len(names)))
    for i in range(n):
        est = solve({key: float(v[i]) for key, v in draws.items()})
        ys[i] = [est[p] for p in names]
    for j, p in enumerate(names):
        std_a, dof_a = type_a[p]
        z = rng.standard_normal(n) if math.isinf(dof_a) else rng.standard_t(dof_a, n)
        ys[:, j] += std_a * z
    tail = 50.0 * (1.0 - coverage)
    lo, hi = np.percentile(ys, [tail, 100.0 - tail], axis=0)
    return {p: (float(ys[:, j].mean()), float(lo[j]), float(hi[j])) for j, p in enumerate(names)}
