"""Ground-truth benchmark, the peers: each installed independent implementation (imucal,
allantools) run on the raw samples of a case's first replicates, as `calib validate` runs
it on an archived run (`pipelines.validation.compare`), and scored per parameter: E_n
against ours, and, where the simulation knows the truth, both tools' errors against it.

A peer not installed, or one that cannot treat the case's procedure, is listed with the
reason; nothing is skipped silently.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from pipelines.validation import compare, peers


class PeerTally:
    """The peers' comparisons of one case, replicate by replicate.

    Parameters
    ----------
    procedure : the case's procedure. gravity : m/s^2. settings : the run's settings
    (turns). truth : name -> true value (SI) of the simulated parameters.
    """

    def __init__(
        self,
        procedure: str,
        gravity: float,
        settings: Mapping[str, Any],
        truth: Mapping[str, float],
    ) -> None:
        self.procedure, self.gravity, self.truth = procedure, gravity, truth
        self.turns = int(settings.get("turns", 1))
        self.entries: dict[str, dict[str, Any]] = {}
        self.rows: dict[str, list[dict[str, Any]]] = {}
        for peer in compare.PEERS:
            version = peers.installed_version(peer)
            entry: dict[str, Any] = {"peer": peer, "version": version, "reason": None}
            if version is None:
                entry |= {"status": "not installed", "reason": f"not installed ({compare.EXTRA})"}
            else:
                entry["status"] = "compared"
            self.entries[peer] = entry
            self.rows[peer] = []

    def add(self, segments: dict[str, Any], ours: Any) -> None:
        """One replicate: its raw segments and our Calibration of them."""
        for peer, entry in self.entries.items():
            if entry["status"] != "compared":
                continue
            try:
                if peer == "imucal":
                    rows, _ = compare.imucal_rows(ours, segments, self.gravity, self.turns, False)
                else:
                    rows, _ = compare.allantools_rows(ours, segments, self.procedure)
            except peers.PeerCannotTreatError as exc:
                entry |= {"status": "cannot treat", "reason": str(exc)}
                continue
            self.rows[peer].append({r["parameter"]: r for r in rows})

    def result(self) -> list[dict[str, Any]]:
        """Per peer: status, reason, version, replicates compared and per parameter the
        E_n figures and the RMS errors of both against the truth (None where unknown)."""
        out = []
        for peer, entry in self.entries.items():
            runs = self.rows[peer] if entry["status"] == "compared" else []
            scores = [self._score(n, runs) for n in (runs[0] if runs else {})]
            doc = {**entry, "replicates": len(runs), "parameters": scores}
            if doc["parameters"]:
                worst = max(doc["parameters"], key=lambda p: p["e_n_max"] or 0.0)
                doc["e_n_max"], doc["e_n_max_parameter"] = worst["e_n_max"], worst["parameter"]
                doc["e_n_within_1"] = float(np.mean([p["e_n_within_1"] for p in doc["parameters"]]))
            out.append(doc)
        return out

    def _score(self, name: str, runs: list[dict[str, dict[str, Any]]]) -> dict[str, Any]:
        rows = [r[name] for r in runs]
        e_n = [r["e_n"] for r in rows if r["e_n"] is not None]
        truth = self.truth.get(name)

        def rms(key: str) -> float | None:
            if truth is None:
                return None
            return math.sqrt(float(np.mean([(r[key] - truth) ** 2 for r in rows])))

        return {
            "parameter": name,
            "e_n_median": float(np.median(e_n)) if e_n else None,
            "e_n_max": max(e_n) if e_n else None,
            "e_n_within_1": float(np.mean([e <= 1.0 for e in e_n])) if e_n else None,
            "rms_error_ours": rms("ours"),
            "rms_error_theirs": rms("theirs"),
        }
