"""Centrifuge procedure, the science: the generic procedure shape.

Labelled segments (``xp_step_4g``, ``zm_1g``, ``xp_zero_90`` ...) -> centrifuge steps ->
`solve_centrifuge` -> a Calibration with canonical names; the settings of a manifest's
``[run.settings]``; a JSON summary of the model. Registered as the ``centrifuge``
procedure in calib_core.procedures.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from calib_core.calibration import Calibration, CheckResult, SegmentResidual
from calib_core.params import AXES
from calib_core.recording import Recording
from calib_core.settings import Setting, Settings, SettingsIn
from calib_core.significance import STEERING, T_TESTS
from calib_core.solvers.centrifuge import solve_centrifuge
from calib_core.solvers.centrifuge_model import (
    DEFAULT_STEER,
    DEFAULT_ZERO_SHIFT_LIMIT,
    RADIUS_FROM,
    CentrifugeModel,
    CentrifugeSettings,
    CentrifugeStep,
    Estimate,
    compensate,
    whole_revolution_mean,
)

# --- the generic procedure shape: labelled segments -> Calibration ---------------

_LABEL = re.compile(r"^([xyz])([pm])_(?:zero_(after_)?(\d+(?:\.\d+)?)|1g|step_(\d+(?:\.\d+)?)g)$")
# The procedure's settings (docs/procedures.md); its solver takes them typed.
SETTINGS = Settings(
    Setting("latitude_deg", "number", "deg", None,
            "site latitude (Earth rate); required, the pipeline takes [site] latitude_deg",
            low=-90.0, high=90.0),
    Setting("alpha", "number", "1", 0.05, "significance level of the t and F tests",
            low=0.0, high=1.0, low_open=True),
    Setting("t_test", "text", "", "two-sided", "t test of each term", choices=T_TESTS),
    Setting("steer", "text", "", DEFAULT_STEER,
            "how the stepwise reduction decides: the model F test then the t tests (the "
            "paper's), the t tests alone, or the largest model F", choices=STEERING),
    Setting("scale_1g", "table", "1", {},
            "per table axis x, y, z the 1 g scale error K - 1 of a static calibration"),
    Setting("common_radius", "bool", "", True, "one effective radius for all positions"),
    Setting("iterations", "integer", "1", 4, "radius / phi_h / model passes", low=1),
    Setting("scale_instability", ("number", "table"), "1", None,
            "relative scale instability from step to step, one value or per axis (absent: "
            "estimated)", low=0.0),
    Setting("zero_shift_limit", "number", "m/s^2", DEFAULT_ZERO_SHIFT_LIMIT,
            "allowed change of a position's zero output before / after its run", low=0.0,
            low_open=True),
    Setting("radius_from", "text", "", "all_records",
            "effective radius from the near-1 g runs (the paper's) or from all records "
            "jointly with the model, each axis's scale held at scale_1g", choices=RADIUS_FROM),
    name="CentrifugeProcedureSettings",
)  # fmt: skip


def step_label(step: CentrifugeStep) -> str:
    """The segment label of a step: "xp_zero_90", "xm_1g", "zp_step_10g"."""
    mount = step.mount[0] + ("p" if step.mount[1] == "+" else "m")
    if step.kind in ("zero", "zero_after"):
        after = "after_" if step.kind == "zero_after" else ""
        return f"{mount}_zero_{after}{step.table_position_deg:g}"
    return f"{mount}_1g" if step.kind == "1g" else f"{mount}_step_{step.nominal_g:g}g"


def steps_from_segments(segments: Mapping[str, Recording]) -> list[CentrifugeStep]:
    """Centrifuge steps from labelled segments.

    Labels: ``<axis><p|m>_zero_<table deg>`` (static zero output at that table
    position, before the run), ``<axis><p|m>_zero_after_<table deg>`` (the same
    after the run, compared with it), ``<axis><p|m>_1g`` (the near-1 g radius run) and
    ``<axis><p|m>_step_<n>g`` (a high-g step); p = the axis points to the
    table axis, m = away. Every recording needs the reference channels
    ``table_angle`` (rad) and ``table_rate`` (rad/s, signed about up).
    """
    steps = []
    for label, rec in segments.items():
        m = _LABEL.match(label)
        if not m:
            raise ValueError(
                f"segment {label!r}: not a centrifuge label; expected e.g. 'xp_zero_90', "
                "'xm_1g' or 'zp_step_10g' (<axis><p|m>_zero_<deg> | _zero_after_<deg> | _1g | "
                "_step_<n>g)"
            )
        mount = m[1] + ("+" if m[2] == "p" else "-")
        if m[4] is not None:
            kind = "zero_after" if m[3] else "zero"
            steps.append(CentrifugeStep(mount, kind, rec, 0.0, float(m[4])))
        elif m[5] is not None:
            steps.append(CentrifugeStep(mount, "step", rec, float(m[5])))
        else:
            steps.append(CentrifugeStep(mount, "1g", rec, 1.0))
    return steps


def settings_from_dict(settings: SettingsIn, gravity: float) -> CentrifugeSettings:
    """CentrifugeSettings from the procedure's typed settings (a mapping is parsed:
    `SETTINGS`, other keys such as the preprocessing tables left out).

    ``latitude_deg`` is required; ``scale_1g`` is a table axis -> K - 1;
    ``scale_instability`` a number, a table axis -> number, or absent (estimate).
    """
    s = SETTINGS.parse(settings)
    if s.latitude_deg is None:
        raise ValueError(
            "centrifuge: settings.latitude_deg is required (site latitude, deg: Earth rate)"
        )
    if set(s.scale_1g) - set(AXES):
        raise ValueError(
            f"centrifuge: settings.scale_1g must map axes x, y, z to K - 1, got {s.scale_1g!r}"
        )
    try:
        return CentrifugeSettings(
            latitude_deg=float(s.latitude_deg),
            gravity=gravity,
            alpha=float(s.alpha),
            t_test=s.t_test,
            steer=s.steer,
            scale_1g={a: float(v) for a, v in s.scale_1g.items()},
            common_radius=s.common_radius,
            iterations=s.iterations,
            scale_instability=s.scale_instability,
            zero_shift_limit=float(s.zero_shift_limit),
            radius_from=s.radius_from,
        )
    except (TypeError, ValueError) as exc:
        raise ValueError(f"centrifuge: bad settings {s.as_dict()}: {exc}") from None


def solve_centrifuge_segments(
    segments: dict[str, Recording], gravity: float, settings: SettingsIn = None
) -> Calibration:
    """The centrifuge as a procedure: labelled segments -> Calibration.

    Parameters
    ----------
    segments : label -> Recording, labels as `steps_from_segments`.
    gravity : local gravity, m/s^2.
    settings : as `settings_from_dict`.

    Returns
    -------
    Calibration with the kept terms by canonical name (acc.bias.x, acc.scale.x,
    acc.k2.x, acc.k2.xy, acc.misalign.xy, ...), the residual of every high-g
    step after compensation, and in `info` the geometry and per axis F,
    F_crit, R^2, t values, removal sequence and the terms not identifiable.
    """
    cs = settings_from_dict(settings, gravity)
    model, record = solve_centrifuge(steps_from_segments(segments), cs)
    cal = Calibration(procedure="centrifuge", gravity=gravity)
    for name, est in model.parameters().items():
        cal.add(name, est.value, est.std)
    for label, rec in segments.items():
        step = steps_from_segments({label: rec})[0]
        if step.kind != "step":
            continue
        mean = whole_revolution_mean(rec)
        f = model.input_force(step.mount, mean.rate)[0]
        r = compensate(model, mean.acc[None, :])[0] - f
        cal.residuals.append(
            SegmentResidual(
                segment=label,
                sensor="acc",
                mean=tuple(float(v) for v in r),
                std=tuple(float(v) for v in rec.acc.std(axis=0, ddof=1)),
                n=len(rec),
            )
        )
    cal.info.update(model_summary(model))
    cal.info["solver_checks"] = [c.to_dict() for c in zero_shift_checks(model)]
    cal.warnings += [c.detail for c in zero_shift_checks(model) if not c.passed]
    cal.info["step_record"] = {"name": record.name, "settings": record.settings}
    return cal


def zero_shift_checks(model: CentrifugeModel) -> list[CheckResult]:
    """One check per position and axis: |zero after - zero before| <= zero_shift_limit."""
    return [
        CheckResult.at_most(
            f"zero_shift:{mount}:{axis}", abs(float(z.shift[i])), z.limit, z.describe(axis)
        )
        for mount, z in model.zero_shift.items()
        for i, axis in enumerate(AXES)
    ]


def model_summary(model: CentrifugeModel) -> dict:
    """JSON-ready facts of a solved model: geometry and per-axis statistics."""

    def est(e: Estimate) -> list[float]:
        return [e.value, e.std]

    axes = {}
    for axis, m in model.axes.items():
        fit, full = m.fit, m.reduction.full
        axes[axis] = {
            "terms": list(m.terms),
            "coef": [float(c) for c in m.coef],
            "std": [float(s) for s in m.std],
            "t": {n: float(t) for n, t in zip(fit.names, fit.t, strict=True)},
            "F": fit.F,
            "F_crit": fit.F_crit,
            "r2": fit.r2,
            "t_crit": fit.t_crit,
            "n": fit.n,
            "k": fit.k,
            "full_F": full.F,
            "full_F_crit": full.F_crit,
            "full_r2": full.r2,
            "removed": [{"term": s.removed, "t": s.t, "p": s.p} for s in m.reduction.steps],
            "not_identifiable": list(m.not_identifiable),
            "nuisance": list(m.nuisance),
            "scale_instability": m.scale_instability,
        }
    return {
        "radius_m": {k: est(v) for k, v in model.radius.items()},
        "radius_1g_m": {k: est(v) for k, v in model.radius_raw.items()},
        "phi_h_rad": {k: est(v) for k, v in model.phi_h.items()},
        "phi_h_1g_rad": {k: est(v) for k, v in model.phi_h_1g.items()},
        "omega_v": model.omega_v,
        "alpha": next(iter(model.axes.values())).fit.alpha,
        "zero_shift_m_s2": {
            m: {"shift": z.shift.tolist(), "std": z.std.tolist(), "limit": z.limit}
            for m, z in model.zero_shift.items()
        },
        "axes": axes,
    }
