"""Method validation, the comparison: an archived run's parameters against a peer's, with
the difference, the combined standard uncertainty and the normalised error E_n."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from storage.db import Archive
from storage.queries.records import RunSummary

PEERS = ("imucal", "allantools")
K_EXPANDED = 2.0  # E_n is taken with expanded uncertainties U = k u_c, k = 2 (metrology.md)
EXTRA = "pip install 'imu-calib[validate]'"


def peer_names(text: str) -> tuple[str, ...]:
    """The peers named by ``--with`` (comma-separated); empty: every peer.

    Raises
    ------
    ValueError naming an unknown peer and the known ones.
    """
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in PEERS]
    if unknown:
        raise ValueError(f"--with: unknown peer {unknown[0]!r}; expected one of {', '.join(PEERS)}")
    return tuple(dict.fromkeys(names)) or PEERS


def comparison_row(
    name: str, ours: float, u_ours: float | None, theirs: float, u_theirs: float | None, unit: str
) -> dict[str, Any]:
    """One parameter compared: E_n = |ours - theirs| / sqrt(U_ours^2 + U_theirs^2), U = k u
    with k = 2; a side that states no uncertainty counts 0 (the row says so: None)."""
    diff = ours - theirs
    u_c = math.hypot(u_ours or 0.0, u_theirs or 0.0)
    e_n = abs(diff) / (K_EXPANDED * u_c) if u_c > 0 else None
    return {
        "parameter": name,
        "ours": ours,
        "u_ours": u_ours,
        "theirs": theirs,
        "u_theirs": u_theirs,
        "difference": diff,
        "u_combined": u_c,
        "e_n": e_n,
        "unit": unit,
    }


def validate_run(archive: Archive, run_id: str, peers: tuple[str, ...]) -> dict[str, Any]:
    """One archived run compared with each peer in `peers`.

    Returns
    -------
    {"run_id", "revision", "procedure", "peers": [one entry per peer: peer, version,
    status ("compared", "not installed", "cannot treat"), reason, parameters (rows of
    `comparison_row`), notes]}. Raises LookupError for an unknown run.
    """
    from calib_core.calibration import Calibration
    from pipelines.ingest.run_loader import load_run
    from pipelines.reprocess import restore_run
    from pipelines.validation import peers as peer_mod
    from storage import queries

    full = queries.full_run_id(archive, run_id)
    exported = queries.export_calibration(archive, full)
    ours = Calibration.from_dict(exported["calibration"])
    summary = queries.run_summary(archive, full)
    with tempfile.TemporaryDirectory(prefix=f"validate_{full}_") as tmp:
        loaded = load_run(restore_run(archive, full, Path(tmp) / full))
    out = []
    for peer in peers:
        version = peer_mod.installed_version(peer)
        entry: dict[str, Any] = {"peer": peer, "version": version, "parameters": [], "notes": []}
        if version is None:
            entry |= {"status": "not installed", "reason": f"{peer} is not installed ({EXTRA})"}
        else:
            try:
                rows, notes = RUNNERS[peer](ours, loaded, summary)
            except peer_mod.PeerCannotTreatError as exc:
                entry |= {"status": "cannot treat", "reason": str(exc)}
            else:
                entry |= {"status": "compared", "reason": None, "parameters": rows, "notes": notes}
        out.append(entry)
    return {
        "run_id": full,
        "revision": exported["revision"],
        "procedure": summary.procedure,
        "peers": out,
    }


def validate_and_archive(archive: Archive, run_id: str, peers: tuple[str, ...]) -> dict[str, Any]:
    """`validate_run`, kept as a sealed validation record of the run (storage.validation);
    the document with its record's ``validation_id``."""
    from pipelines.provenance import SOFTWARE_VERSION
    from storage.validation import archive_validation

    doc = validate_run(archive, run_id, peers)
    doc["software_version"] = SOFTWARE_VERSION
    doc["validation_id"] = archive_validation(archive, doc["run_id"], doc, SOFTWARE_VERSION)
    return doc


def _imucal(ours: Any, loaded: Any, summary: RunSummary) -> tuple[list, list[str]]:
    """imucal against our archived parameters: every parameter both estimate."""
    m = loaded.manifest
    turns = int(m.run.settings.get("turns", 1))
    turntable = any(e.kind == "rate_table" for e in summary.equipment)
    rows, notes = imucal_rows(ours, loaded.segments, m.gravity(), turns, turntable)
    if not rows:
        raise ValueError(f"run {summary.run_id}: no parameter both estimate")
    return rows, notes


def imucal_rows(
    ours: Any, segments: dict[str, Any], gravity: float, turns: int, turntable: bool
) -> tuple[list[dict[str, Any]], list[str]]:
    """imucal's solution of the raw `segments` against our Calibration `ours`: a row
    (`comparison_row`) per parameter both estimate, and the notes on the conventions.
    Raises PeerCannotTreatError where imucal cannot treat the segments."""
    from calib_core import params
    from pipelines.validation.peers import imucal_parameters, imucal_turn_uncertainty

    theirs = imucal_parameters(segments, gravity, turns, turntable)
    u_theirs = imucal_turn_uncertainty(segments, gravity, turns)
    rows = [
        comparison_row(name, p.value, p.std, theirs[name], u_theirs.get(name), params.unit_of(name))
        for name, p in ours.parameters.items()
        if name in theirs
    ]
    notes = [
        f"imucal {'TurntableCalibration' if turntable else 'FerrarisCalibration'} on the raw "
        f"samples, gravity {gravity:.6g} m/s^2, {turns} turn(s) per axis; imucal states no "
        "uncertainty: E_n takes ours alone (k = 2), but for the gyro scale and misalignment, "
        "whose Type A of imucal's method (whole records, one sense) our solver states",
        "imucal's accelerometer bias is each channel's own face pair (Ferraris eq. 20); ours "
        "averages the three pairs (docs/validation.md)",
    ]
    return rows, notes


def _allantools(ours: Any, loaded: Any, summary: RunSummary) -> tuple[list, list[str]]:
    """allantools' Allan deviation against ours, and the noise terms read from each."""
    from pipelines.validation.peers import PeerCannotTreatError

    if loaded.streamed is not None:
        raise PeerCannotTreatError("allantools is compared on one static record held in memory")
    return allantools_rows(ours, loaded.segments, summary.procedure)


def allantools_rows(
    ours: Any, segments: dict[str, Any], procedure: str
) -> tuple[list[dict[str, Any]], list[str]]:
    """allantools' Allan deviation of the one static record in `segments` against ours (in
    the notes), and a row per noise term read from each curve by our reading. Raises
    PeerCannotTreatError where the run keeps no Allan deviation or is not one record."""
    from calib_core.nav_noise import nav_noise
    from calib_core.noise import AllanResult, noise_parameters, white_noise_edf
    from pipelines.validation.peers import PeerCannotTreatError, allantools_curves, rate_of

    info = ours.info
    if "allan" not in info or "noise_parameters" not in info:
        raise PeerCannotTreatError(
            f"procedure {procedure} keeps no Allan deviation (a static-bias run does)"
        )
    if len(segments) != 1:
        raise PeerCannotTreatError("allantools is compared on one static record held in memory")
    rec = next(iter(segments.values()))
    rate_hz = rate_of(rec)
    nav = nav_noise(info)
    rows: list[dict[str, Any]] = []
    notes: list[str] = []
    for sensor, data in (("gyr", rec.gyr), ("acc", rec.acc)):
        allan = info["allan"][sensor]
        taus = np.asarray(allan["taus"], dtype=float)
        adev_ours = np.asarray(allan["adev"], dtype=float)
        adev_theirs = allantools_curves(np.asarray(data, dtype=float), rate_hz, taus)
        half = (np.asarray(allan["ci_high"]) - np.asarray(allan["ci_low"])) / 2.0
        worst = float(np.max(np.abs(adev_theirs - adev_ours) / half))
        rel = float(np.max(np.abs(adev_theirs / adev_ours - 1.0)))
        notes.append(
            f"{sensor} Allan deviation at {len(taus)} cluster times: largest relative "
            f"difference {rel:.2e}, {worst:.3g} of our 68 % half-interval; allantools "
            f"reads the raw samples, ours those after the n-sigma clip "
            f"({sum(info.get('outliers', {}).get(sensor, []))} replaced)"
        )
        m = np.rint(taus * rate_hz)
        for i, a in enumerate("xyz"):
            fit = info["noise_parameters"][sensor][i]
            curve = AllanResult(
                taus,
                adev_theirs[:, i],
                np.asarray(allan["n_clusters"]),
                adev_theirs[:, i],
                adev_theirs[:, i],
                white_noise_edf(len(rec.t), m),
                rate_hz,
                len(rec.t),
            )
            theirs = noise_parameters(curve, method=fit["method"])
            for term, attr, navterm in (
                ("noise_density", "arw", getattr(nav, f"{sensor}_noise_density")),
                ("random_walk", "rrw", getattr(nav, f"{sensor}_random_walk")),
            ):
                rows.append(
                    comparison_row(
                        f"{sensor}.{term}.{a}",
                        float(navterm.values[i]),
                        float(navterm.stds[i]),
                        float(getattr(theirs, attr)),
                        None,
                        navterm.unit,
                    )
                )
    notes.append(
        "noise terms: continuous-time densities (N at tau = 1 s, K at tau = 3 s), read from "
        "each curve by our fit (calib_core.noise); u ours: the parametric bootstrap of the "
        "fit (calib_core.nav_noise); allantools states no uncertainty"
    )
    return rows, notes


RUNNERS = {"imucal": _imucal, "allantools": _allantools}
