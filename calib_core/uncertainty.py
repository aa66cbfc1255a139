"""Uncertainty budget per parameter (GUM, JCGM 100) and its Monte Carlo check (JCGM 101).

Science only (numpy/scipy). A budget combines the Type A standard uncertainty of the fit with
Type B inputs of the reference (local gravity, cube/fixture angles, table rate and angle, ...),
each with its distribution. Sensitivity coefficients are computed through the solver by central
finite differences of the solve with respect to each Type B input. The combined standard
uncertainty, the Welch-Satterthwaite effective degrees of freedom, the coverage factor for about
95 % and the expanded uncertainty U follow. The coverage factor is Student's t at nu_eff when every
contributing input is normal (or t); when a rectangular, triangular or u-shaped input contributes,
the combined distribution is not near a t (GUM G.6.5, JCGM 101 5.7) and k is taken from the
propagated distribution of the linearised model itself (JCGM 101 sampling of
y = sum c_i x_i; ``Budget.k_method`` says which). A run without equipment knowledge gets a budget
labelled Type A only (``Budget.type_a_only``), never a silently smaller U.

The Monte Carlo check draws every input from its stated distribution, pushes each draw through
the same solver and takes the probabilistically symmetric 95 % interval (numpy sampling).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib_core.distributions import norm_ppf, t_ppf

# Divisor from a stated half-width a (or expanded U at k for "normal") to a standard uncertainty.
_DIVISORS = {
    "rectangular": math.sqrt(3.0),
    "triangular": math.sqrt(6.0),
    "u-shaped": math.sqrt(2.0),
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
        return self.value + self.std * standard_draws(self.distribution, self.dof, rng, n)


def standard_draws(distribution: str, dof: float, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n,) draws of a zero-mean input of unit standard uncertainty (JCGM 101 6.4).

    A normal input with finite degrees of freedom is a scaled Student t (JCGM 101 6.4.9: the
    t variable times the standard uncertainty, as for a Type A mean).
    """
    if distribution == "normal":
        return rng.standard_normal(n) if math.isinf(dof) else rng.standard_t(dof, n)
    a = _DIVISORS[distribution]  # half-width of the unit-variance distribution
    if distribution == "rectangular":
        return rng.uniform(-a, a, n)
    if distribution == "triangular":
        return rng.triangular(-a, 0.0, a, n)
    return a * np.sin(rng.uniform(-np.pi, np.pi, n))  # u-shaped (arcsine)


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


EQUIPMENT_UNKNOWN = "equipment unknown"
K_STUDENT = "Student t at nu_eff (GUM G.4)"
K_PROPAGATED = "propagated distribution of the linearised model (JCGM 101)"
# Draws of the linearised model's combined distribution: the 2.5 % / 97.5 % quantiles then
# scatter by ~0.3 % of U (normal case), below the two significant digits U is reported with.
K_DRAWS = 100_000


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
    k_method: str = K_STUDENT

    @property
    def label(self) -> str:
        """ "Type A only (<why>)", e.g. "Type A only (equipment unknown)", or "Type A + Type B"."""
        if not self.type_a_only:
            return "Type A + Type B"
        return f"Type A only ({self.notes[0] if self.notes else EQUIPMENT_UNKNOWN})"

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly document of the budget."""
        return {
            "parameter": self.parameter,
            "value": self.value,
            "unit": self.unit,
            "rows": [r.to_dict() for r in self.rows],
            "uc": self.uc,
            "nu_eff": None if math.isinf(self.nu_eff) else self.nu_eff,
            "k": self.k,
            "U": self.U,
            "coverage": self.coverage,
            "type_a_only": self.type_a_only,
            "label": self.label,
            "notes": list(self.notes),
            "k_method": self.k_method,
        }

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> Budget:
        """Read back `to_dict` (None degrees of freedom are infinite)."""

        def dof(v: Any) -> float:
            return math.inf if v is None else float(v)

        rows = tuple(Contribution(**{**r, "dof": dof(r["dof"])}) for r in doc["rows"])
        return cls(
            doc["parameter"],
            doc["value"],
            doc["unit"],
            rows,
            doc["uc"],
            dof(doc["nu_eff"]),
            doc["k"],
            doc["U"],
            doc["coverage"],
            doc["type_a_only"],
            tuple(doc["notes"]),
            doc.get("k_method", K_STUDENT),
        )


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


def propagated_coverage_factor(
    rows: Sequence[Contribution], coverage: float = 0.95, draws: int = K_DRAWS
) -> float:
    """k = U / u_c of the distribution of y = sum c_i x_i (JCGM 101 on the linearised model).

    Each row's input is drawn from its own distribution (Type A and normal inputs with finite
    dof as scaled t) times its contribution; the normal inputs with infinite dof are one normal
    term (their sum is exactly normal). U is half the probabilistically symmetric coverage
    interval. The draws are fixed (seeded per row position), so a budget is reproducible.
    """
    live = [r for r in rows if r.contribution > 0]
    uc = math.sqrt(sum(r.contribution**2 for r in live))
    if uc == 0.0:
        return coverage_factor(math.inf, coverage)
    normal = [r.contribution for r in live if r.distribution == "normal" and math.isinf(r.dof)]
    y = math.sqrt(sum(u * u for u in normal)) * _unit_draws("normal", math.inf, 0, draws)
    others = [r for r in live if not (r.distribution == "normal" and math.isinf(r.dof))]
    for i, r in enumerate(others, start=1):
        y = y + r.contribution * _unit_draws(r.distribution, r.dof, i, draws)
    tail = 50.0 * (1.0 - coverage)
    lo, hi = np.percentile(y, [tail, 100.0 - tail])
    return float((hi - lo) / 2.0 / uc)


@functools.lru_cache(maxsize=64)
def _unit_draws(distribution: str, dof: float, index: int, draws: int) -> np.ndarray:
    """Fixed unit-variance draws of the `index`-th input (read-only, shared between budgets)."""
    out = standard_draws(distribution, dof, np.random.default_rng([index, draws]), draws)
    out.flags.writeable = False
    return out


def combine(
    parameter: str,
    value: float,
    rows: Sequence[Contribution],
    unit: str = "",
    coverage: float = 0.95,
    type_a_only: bool = False,
    notes: Sequence[str] = (),
) -> Budget:
    """Combine uncorrelated budget rows into u_c, nu_eff, k and U.

    k is Student's t at nu_eff when every contributing input is normal (GUM); when a
    non-normal (rectangular, triangular, u-shaped) input contributes, k is that of the
    linearised model's propagated distribution (`propagated_coverage_factor`).
    """
    u = [r.contribution for r in rows]
    uc = float(math.sqrt(sum(x * x for x in u)))
    nu = welch_satterthwaite(u, [r.dof for r in rows])
    if any(r.distribution != "normal" and r.contribution > 0 for r in rows):
        k, method = propagated_coverage_factor(rows, coverage), K_PROPAGATED
    else:
        k, method = coverage_factor(nu, coverage), K_STUDENT
    return Budget(
        parameter,
        value,
        unit,
        tuple(rows),
        uc,
        nu,
        k,
        k * uc,
        coverage,
        type_a_only,
        tuple(notes),
        method,
    )


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
        out[q.name] = {p: (hi[p] - lo[p]) / (2.0 * h) for p in hi if p in lo}
    return out


def budgets(
    solve: Solve,
    inputs: Sequence[InputQuantity],
    type_a: Mapping[str, tuple[float, float]],
    units: Mapping[str, str] | None = None,
    coverage: float = 0.95,
    *,
    estimates: Mapping[str, float] | None = None,
    notes: Sequence[str] = (),
    reason: str = EQUIPMENT_UNKNOWN,
) -> dict[str, Budget]:
    """Budget of every parameter of `type_a` (name -> (std, dof)).

    estimates : the values to report (default: `solve` at the nominal inputs); a parameter the
        solve does not return has no Type B sensitivity.
    notes : added to every budget (e.g. sources not evaluated).
    With no `inputs` every budget is labelled Type A only, `reason` saying why.
    """
    units = units or {}
    values = {**solve({q.name: q.value for q in inputs}), **(estimates or {})}
    sens = sensitivities(solve, inputs) if inputs else {}
    out: dict[str, Budget] = {}
    for name, (std_a, dof_a) in type_a.items():
        rows = [
            Contribution(
                "fit (Type A)", "A", "normal", std_a, 1.0, std_a, dof_a, units.get(name, "")
            )
        ]
        for q in inputs:
            c = sens[q.name].get(name, 0.0)
            rows.append(
                Contribution(q.name, "B", q.distribution, q.std, c, abs(c) * q.std, q.dof, q.unit)
            )
        why = (*notes,) if inputs else (reason, *notes, "Type B sources not evaluated")
        out[name] = combine(
            name,
            float(values[name]),
            rows,
            units.get(name, ""),
            coverage,
            type_a_only=not inputs,
            notes=why,
        )
    return out


def monte_carlo(
    solve: Solve,
    inputs: Sequence[InputQuantity],
    type_a: Mapping[str, tuple[float, float]],
    n: int = 2000,
    rng: np.random.Generator | None = None,
    coverage: float = 0.95,
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
        ys[:, j] += std_a * standard_draws("normal", dof_a, rng, n)
    tail = 50.0 * (1.0 - coverage)
    lo, hi = np.percentile(ys, [tail, 100.0 - tail], axis=0)
    return {p: (float(ys[:, j].mean()), float(lo[j]), float(hi[j])) for j, p in enumerate(names)}
