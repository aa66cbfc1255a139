"""A static-bias run whose recording is larger than its memory limit, processed in chunks.

The data file is read once by its format's streamer (`pipelines.ingest.streaming`): its
bytes hashed and copied into the archive's raw store, its samples written as the run's
samples Parquet (under a temporary name beside their archived place), the first-pass
statistics kept. The solve reads the Parquet back, a channel at a time (outlier rule, Allan
deviation and noise fits; the temperature the conditions judge on the way); the
as-found solve, when the unit comes back, reads it again through the earlier
calibration. Everything else of `pipelines.process` takes the run as it takes one read
into memory (`LoadedRun.streamed`); no step holds the whole record.

A record's results and the settings it may use do not depend on its size: the segment's
time window is applied as the file is read, the preprocessing chain (`preprocess`) runs
on the record as in memory (its outlier step leaves a segment that is not a static
position as it is, here as there). A run whose settings need the whole record in memory
(sections, separate acc/gyr files, reference channels, a verification segment,
sync/segmentation/low-pass, the outlier step of a static position, a reference
correction) is read into memory whatever its size (`stream_plan`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import UTC
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from calib_core import procedures
from calib_core.calibration import Calibration, StepRecord
from calib_core.checks import MODEL_PREFIX
from calib_core.conditions import temperature_block
from calib_core.preprocess.chain import (
    DEFAULT_OUTLIERS,
    OUTLIERS,
    is_static,
    preprocess,
    replaced_checks,
    settings_table,
)
from calib_core.procedures.static_bias import MEMORY_LIMIT
from calib_core.recording import RANGE_MARGIN, Recording, first_range_hit
from calib_core.streamed import RecordSummary, TemperatureTrend, load_compiled
from calib_core.uncertainty import Budget
from pipelines.ingest import RunSource
from pipelines.ingest.csv_layout import layout_of
from pipelines.ingest.errors import IngestError
from pipelines.ingest.manifest import RunManifest, SegmentSpec, check_segments, load_manifest
from pipelines.ingest.run_loader import (
    MANIFEST_NAME,
    LoadedRun,
    RawFile,
    check_window_end,
    check_window_inside,
    data_file,
    empty_window,
    range_limits,
    refuse_range_hit,
    with_lab_site,
)
from pipelines.ingest.streaming import STREAMERS, StreamedRecord
from pipelines.streamed_solve import samples_chunks, solve_streamed
from pipelines.uncertainty import uncertainty_step
from storage import rawstore

MB = 1_000_000  # bytes: the unit of memory_limit_mb
PREPROCESSING = ("sync", "segmentation", "lowpass")  # tables the streamed route does not apply


def memory_limit(procedure: procedures.Procedure, settings: dict[str, Any]) -> int:
    """The run's memory limit, bytes (``run.settings.memory_limit_mb``, checked)."""
    setting = procedure.settings.items[MEMORY_LIMIT]
    value = settings.get(MEMORY_LIMIT, setting.default)
    setting.check(value)
    return int(value * MB)


@dataclass(frozen=True)
class StreamPlan:
    """A run the streamed route takes: its validated manifest and its one data file."""

    folder: Path
    manifest: RunManifest
    manifest_path: Path
    text: str
    segment: SegmentSpec
    path: Path
    memory_limit: int


def stream_plan(source: RunSource) -> StreamPlan | None:
    """The streamed route's plan of a run; None when the run is read into memory.

    A run of a procedure that streams (`Procedure.stream_solver`: static_bias) whose data
    file is larger than its memory limit is streamed, unless its settings need the whole
    record (`in_memory_only`; `pipelines.process` reads a run whose reference is corrected
    into memory too): it is then read into memory, so that the same settings give the
    same results.

    Raises
    ------
    IngestError naming the manifest and the field of a memory limit that is not a number
    >= 1.
    """
    if source.kind != "manifest":
        return None
    manifest_path = source.folder / MANIFEST_NAME
    manifest = load_manifest(manifest_path)
    procedure = procedures.get(manifest.run.procedure)
    if procedure.stream_solver is None or len(manifest.segments) != 1:
        return None
    where = str(manifest_path)
    seg = manifest.segments[0]
    root = source.folder.resolve()
    paths = [data_file(source.folder, root, seg, 0, name, where) for name in seg.files]
    try:
        limit = memory_limit(procedure, manifest.run.settings)
    except ValueError as exc:
        raise IngestError(str(exc), file=where, field=f"run.settings.{MEMORY_LIMIT}") from None
    size = sum(p.stat().st_size for p in paths)
    if size <= limit or in_memory_only(manifest, seg, paths) is not None:
        return None
    check_segments(manifest, where)
    manifest = with_lab_site(manifest, where)
    text = manifest_path.read_text(encoding="utf-8")
    return StreamPlan(source.folder, manifest, manifest_path, text, seg, paths[0], limit)


def in_memory_only(manifest: RunManifest, seg: SegmentSpec, paths: list[Path]) -> str | None:
    """What of the run needs its whole record in memory, or None (it may be streamed)."""
    kind = manifest.format.kind
    if kind not in STREAMERS:
        return f"format kind {kind!r} (streamed: {', '.join(sorted(STREAMERS))})"
    if len(paths) != 1:
        return "separate acc_file and gyr_file"
    outliers = settings_table(manifest.run.settings, "outliers", OUTLIERS) or {}
    if is_static(seg.label) and {**DEFAULT_OUTLIERS, **outliers}["method"] != "none":
        return "the iterative outlier step of a static position"
    if seg.section is not None or manifest.format.section_column is not None:
        return "sections"
    if seg.verification:
        return "a verification segment"
    given = [t for t in PREPROCESSING if manifest.run.settings.get(t) is not None]
    if given:
        return f"[run.settings.{given[0]}]"
    if kind == "csv":
        refs = [r for r in layout_of(paths[0], manifest.format, sections=False).roles if ":" in r]
        if refs:
            return f"reference channels ({', '.join(refs)})"
    return None


def load_streamed(plan: StreamPlan, root: Path, pending: rawstore.PendingFiles) -> LoadedRun:
    """Hash and stage the manifest, stream the data file (hash, raw copy, samples' Parquet,
    statistics) and check the sensor's range; the run as `load_run` gives it, its record
    in `streamed`."""
    m, seg = plan.manifest, plan.segment
    where = str(plan.manifest_path)
    staged = pending.stage_raw(root, plan.manifest_path)
    raw = [RawFile(plan.manifest_path, MANIFEST_NAME, *staged, "manifest")]
    gyro, acc = range_limits(m, where)
    # Beside their archived place (a rename at the archive's commit); the run id is not
    # known before the file is hashed, the folder is.
    folder = rawstore.samples_path(root, m.unit.serial, m.run.started.astimezone(UTC), "x").parent
    samples = pending.temp_file(folder, "samples")
    copy = pending.temp_file(Path(root) / "objects", "incoming")
    _HASHER.submit(load_compiled)  # beside the pass: the solve's compiled loops, from their cache
    window = None
    if seg.start_s is not None or seg.end_s is not None:
        start, end = seg.start_s, seg.end_s
        window = (-math.inf if start is None else start, math.inf if end is None else end)
    result = STREAMERS[m.format.kind](
        plan.path,
        m.format,
        samples,
        copy_to=copy,
        label=seg.label,
        memory_limit=plan.memory_limit,
        window=window,
    )
    result.first.close()  # its last chunk's statistics are in (every streamer's)
    pending.adopt_raw(root, copy, result.sha256)
    raw.append(RawFile(plan.path, seg.file, result.sha256, result.size, m.format.kind))
    if window is not None:
        _check_window(result, samples, plan)
    _check_range(result.first, samples, plan, gyro, acc)
    # Hashed while the solve reads the file (hashlib releases the GIL).
    sha = _HASHER.submit(lambda: rawstore.hash_and_size(samples)[0])
    record = StreamedRecord(seg.label, result, sha, plan.memory_limit)
    return LoadedRun(plan.folder, m, plan.text, {}, raw, set(), streamed=record)


_HASHER = ThreadPoolExecutor(max_workers=1, thread_name_prefix="calib-samples-hash")


def _check_window(result, samples: Path, plan: StreamPlan) -> None:
    """`load_run`'s checks of a segment's time window: mostly inside the data, samples in
    it, and not running past the end of the data while the unit still turns there."""
    where, (t0, t1), n = str(plan.manifest_path), result.span, result.first.n
    check_window_inside(plan.segment, 0, where, t0, t1)
    if n == 0:
        raise empty_window(plan.segment, 0, where, t0, t1)
    if n < 20:
        return

    def ends() -> tuple[np.ndarray, np.ndarray]:
        parquet = pq.ParquetFile(samples)
        cols = [f"gyr_{a}" for a in "xyz"]
        head = parquet.read_row_group(0, columns=cols)
        tail = parquet.read_row_group(parquet.num_row_groups - 1, columns=cols)
        if tail.num_rows < 10:  # the last row group short: the one before it too
            before = parquet.read_row_group(parquet.num_row_groups - 2, columns=cols)
            tail = pa.concat_tables([before, tail])
        rows = lambda table: np.column_stack([c.to_numpy() for c in table.columns])  # noqa: E731
        return rows(head)[:10], rows(tail)[-10:]

    check_window_end(plan.segment, 0, where, t1, result.first.step.median(), ends)


def _check_range(first, samples: Path, plan: StreamPlan, gyro, acc) -> None:
    """`load_run`'s range check: the channels' extremes from the first pass; only when one
    comes near the range are the samples read again for the first reading at it."""
    near = False
    for cols, full in ((slice(0, 3), gyro), (slice(3, 6), acc)):
        if full is not None:
            limit = full * (1.0 - RANGE_MARGIN)
            near |= bool((first.low[cols] <= -limit).any() or (first.high[cols] >= limit).any())
    if not near:
        return
    for t, g, a in samples_chunks(samples, plan.memory_limit):
        hit = first_range_hit(Recording(t=t, acc=a, gyr=g), gyro, acc)
        if hit is not None:
            refuse_range_hit(hit, plan.manifest, plan.segment, [plan.path])


def solve_streamed_run(
    loaded: LoadedRun, procedure: str | None = None, settings: dict[str, Any] | None = None
) -> tuple[Calibration, list[StepRecord], dict[str, Any], dict[str, Budget], dict]:
    """`pipelines.process.solve_loaded` of a streamed run: the same five results, the fit
    segments empty (nothing downstream reads them: `as_found_solver`)."""
    m, rec = loaded.manifest, loaded.streamed
    assert rec is not None
    settings = {**m.run.settings, **(settings or {})}
    procedure = procedure or m.run.procedure
    if procedures.get(procedure).stream_solver is None:
        raise ValueError(
            f"a streamed record is solved by a procedure that streams, not {procedure!r}"
        )
    first = rec.result.first
    span = RecordSummary(rec.label, first.n, first.t_first, first.t_last, None, None)
    # The chain as in memory: the route is chosen so that none of its steps needs the
    # samples (`in_memory_only`); the record stands in for them.
    started = time.perf_counter()
    _, steps = preprocess({rec.label: span}, settings, gravity=m.gravity())
    steps[-1].statistics["preprocess_seconds"] = round(time.perf_counter() - started, 4)
    checks = replaced_checks(steps)
    trend = TemperatureTrend(rec.result.temp_finite, temperature_block(span))

    cal, record = procedures.solve_step(
        {},
        {**settings, "procedure": procedure, "gravity": m.gravity()},
        solver=record_solver(rec, procedure, trend=trend),
    )
    record.statistics["segments"] = 1
    cal.info["solver_checks"] = [not_done(c) for c in cal.info.get("solver_checks", [])] + checks
    rec.summary = dataclasses.replace(span, temp_means=trend.means(), temp_slope=trend.slope())
    budgets, budget_step = uncertainty_step(cal, {}, settings, m)
    return cal, [*steps, record, budget_step], settings, budgets, {}


def record_solver(
    rec: StreamedRecord, procedure: str, **options: Any
) -> Callable[[dict, float, dict[str, Any]], Calibration]:
    """The `procedures.solve_step` solver of a streamed record: `solve_streamed` of its
    samples by `procedure` (`options`: its ``trend`` or ``chunks``)."""

    def solver(_segments: dict, gravity: float, given: dict[str, Any]) -> Calibration:
        return solve_streamed(
            rec.result,
            given,
            label=rec.label,
            gravity=gravity,
            memory_limit=rec.memory_limit,
            procedure=procedure,
            **options,
        )

    return solver


def not_done(check: dict) -> dict:
    """A check the route could not make (``passed`` None) as the archive keeps it: a
    ``model:`` check that did not pass (verdict "needs review": a person looks)."""
    if check["passed"] is not None:
        return check
    name = check["name"]
    return {**check, "name": f"{MODEL_PREFIX}{name}", "passed": False,
            "detail": f"{check['detail']}; review the record before use"}  # fmt: skip


def as_found_solver(
    loaded: LoadedRun, cal: Calibration, settings: dict[str, Any]
) -> Callable[[Calibration], Calibration]:
    """The as-found solve of a streamed run: its samples, read again in chunks, corrected
    by the earlier calibration, solved by the run's procedure (`calib_core.as_found`)."""
    rec = loaded.streamed
    assert rec is not None

    def found(before: Calibration) -> Calibration:
        def chunks() -> Iterator[tuple]:
            for t, gyr, acc in samples_chunks(rec.result.samples, rec.memory_limit):
                acc_c, gyr_c = before.correct(acc, gyr)
                yield t, gyr_c, acc_c

        solver = record_solver(rec, cal.procedure, chunks=chunks)
        return procedures.solve(cal.procedure, {}, cal.gravity, dict(settings), solver)

    return found


def conditions_segments(loaded: LoadedRun) -> dict[str, Any]:
    """What the conditions take of the run's records: its summary for a streamed one."""
    rec = loaded.streamed
    if rec is None:
        return loaded.segments
    if rec.summary is None:
        raise ValueError("streamed record: the conditions need the solve's pass first")
    return {rec.label: rec.summary}
