"""Find runs in the paths a user gives, and load one run: manifest, segments, raw file hashes.

Two kinds of run folder are recognised:

- a folder with a ``run.toml`` manifest (docs/manifest.md): its ``[format]``
  section names the reader, its ``[[segments]]`` say which file or time
  window is which segment;
- a folder of MPU-6000 files ``<serial>_<axis>_<up|dn|cw|ccw>.txt`` without a
  manifest: one run per serial, with a manifest synthesised from the file
  names (model MPU-6000, procedure six_position_integral, tolerance profile
  mpu6000, standard gravity, started = newest file modification time, UTC).
  Re-processing from the archive (`calib reprocess`) restores the files'
  modification times to the archived start time, so the same manifest results.

The reader of each ``format.kind`` is looked up in pipelines.ingest.readers.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import numpy as np

from calib_core.recording import RangeHit, Recording, first_range_hit
from calib_core.units import DEG, STANDARD_GRAVITY
from pipelines.ingest.csv_reader import read_csv_pair, read_csv_sections
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import check_readings
from pipelines.ingest.manifest import (
    RunManifest,
    SegmentSpec,
    check_segments,
    load_manifest,
    run_manifest,
    sensor_ranges,
)
from pipelines.ingest.mpu6000 import (
    check_complete,
    find_mpu6000_runs,
    parse_file_name,
)
from pipelines.ingest.readers import imutk_format, reader_for
from pipelines.lab import lab_site
from storage.rawstore import hash_and_size

if TYPE_CHECKING:
    from pipelines.ingest.streaming import StreamedRecord

MANIFEST_NAME = "run.toml"


@dataclass(frozen=True, order=True)
class RunSource:
    """One run found on disk, not yet read.

    Attributes
    ----------
    folder : the run folder.
    kind : ``"manifest"`` (a run.toml describes it) or ``"mpu6000"`` (file names only).
    serial : the serial of an MPU-6000 run (a folder may hold several); None for manifests.
    """

    folder: Path
    kind: str
    serial: str | None = None

    @property
    def name(self) -> str:
        """Short name for messages: the folder, plus the serial for MPU-6000 runs."""
        return f"{self.folder} [{self.serial}]" if self.serial else str(self.folder)


@dataclass(frozen=True)
class RawFile:
    """One input file of a run, identified by content.

    Attributes
    ----------
    path : where it was read from.
    name : its name relative to the run folder (as the manifest names it).
    sha256 : hex digest of its bytes.
    size : bytes.
    format : ``"manifest"`` for run.toml, else the format kind (``"csv"``, ``"mpu6000"``, ...).
    """

    path: Path
    name: str
    sha256: str
    size: int
    format: str


@dataclass
class LoadedRun:
    """A run read into memory.

    Attributes
    ----------
    folder : the run folder.
    manifest : the validated (or, for MPU-6000 folders, synthesised) manifest.
    manifest_text : the run.toml text as read, None when synthesised.
    segments : label -> Recording (SI units), in manifest order.
    raw_files : every input file with its hash, run.toml first.
    verification_labels : labels of segments kept out of the fit.
    findings : what the readers found about the files without refusing them (a log read
        to its last whole record), as CheckResult fields; the run's checks name them.
    streamed : a record larger than the memory limit, streamed instead of read
        (`pipelines.ingest.streaming.StreamedRecord`; `segments` is then empty).
    """

    folder: Path
    manifest: RunManifest
    manifest_text: str | None
    segments: dict[str, Recording]
    raw_files: list[RawFile]
    verification_labels: set[str]
    streamed: StreamedRecord | None = None
    findings: list[dict] = field(default_factory=list)


# (sha256, size) of a raw file, e.g. `storage.rawstore.hash_and_size`.
FileHasher = Callable[[Path], tuple[str, int]]


def _sources_in(folder: Path) -> list[RunSource]:
    """Runs held directly by `folder` (not its subfolders)."""
    if (folder / MANIFEST_NAME).is_file():
        return [RunSource(folder, "manifest")]
    serials = find_mpu6000_runs(folder, complete=False)
    return [RunSource(folder, "mpu6000", serial) for serial in serials]


def discover_runs(paths: list[Path], depth: int = 2) -> list[RunSource]:
    """The runs in `paths`, one entry per run, sorted by folder and serial.

    Parameters
    ----------
    paths : run folders (with a run.toml), MPU-6000 folders (one run per serial
        found), folders holding such folders (searched `depth` levels down),
        or a run.toml file.
    depth : how many folder levels below a given path are searched.

    Returns
    -------
    list of RunSource (folder, kind "manifest" or "mpu6000", serial), for
    `load_run` or `process_run`.

    Raises
    ------
    IngestError for a path that does not exist or holds no recognisable run.
    """
    found: set[RunSource] = set()
    for given in paths:
        path = Path(given)
        if not path.exists():
            raise IngestError("path does not exist", file=path)
        if path.is_file():
            if path.name != MANIFEST_NAME:
                raise IngestError(
                    f"expected a run folder or a {MANIFEST_NAME}, got a file", file=path
                )
            path = path.parent
        level = [path]
        runs: list[RunSource] = []
        for _ in range(depth + 1):
            below: list[Path] = []
            for folder in level:
                here = _sources_in(folder)
                runs += here
                if not here:  # a run folder's own subfolders are not runs of their own
                    below += sorted(
                        p for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")
                    )
            level = below
        if not runs:
            raise IngestError(
                f"no run found: expected a folder with a {MANIFEST_NAME} or MPU-6000 files "
                f"named <serial>_<x|y|z>_<up|dn|cw|ccw>.txt, or folders holding them "
                f"(searched {depth} levels down)",
                file=path,
            )
        found.update(runs)
    return sorted(found)


def read_run(path: str | Path, serial: str | None = None) -> LoadedRun:
    """Read the one run at `path` into memory (nothing is archived).

    Parameters
    ----------
    path : a run folder with a run.toml, the run.toml itself, or a folder of
        MPU-6000 files (``<serial>_<x|y|z>_<up|dn|cw|ccw>.txt``).
    serial : which unit, when an MPU-6000 folder holds the files of several.

    Returns
    -------
    LoadedRun: ``manifest`` (unit, run, environment, segments), ``segments``
    (label -> Recording in SI units: t s, acc m/s^2, gyr rad/s, temp deg C) and
    ``raw_files`` with their SHA-256.

    Raises
    ------
    IngestError naming the path when it holds no run or several (give `serial`),
    or the file, line or manifest field of the first problem in the run.
    """
    sources = discover_runs([Path(path)], depth=0)
    if serial is not None:  # a manifest's run (serial None here) names its unit itself
        sources = [s for s in sources if s.serial in (None, serial)]
    if len(sources) != 1:
        which = f" of serial {serial}" if serial else ""
        found = ", ".join(s.name for s in sources) or "none"
        raise IngestError(
            f"expected one run{which} here, found {len(sources)} ({found}): give a run "
            "folder, its run.toml or (calib apply) one MPU-6000 file",
            file=Path(path),
        )
    return load_run(sources[0])


def load_run(source: RunSource, *, hash_file: FileHasher = hash_and_size) -> LoadedRun:
    """Read a run: validate its manifest, read and cut its segments, hash its raw files.

    Parameters
    ----------
    source : the run on disk.
    hash_file : ``hash_file(path) -> (sha256, size)`` of each raw file, after the
        file was read. `pipelines.process.process_run` passes
        `storage.rawstore.PendingFiles.stage_raw`, which copies the file towards
        the archive's object store while hashing it (one read and one hash per file).

    Returns
    -------
    LoadedRun (manifest, segments as Recordings in SI units, raw files with hashes).

    Raises
    ------
    IngestError naming the file, line or manifest field of the first problem.
    """
    if source.kind == "mpu6000":
        return _load_mpu6000_folder(source.folder, source.serial, hash_file)
    manifest_path = source.folder / MANIFEST_NAME
    manifest = load_manifest(manifest_path)
    text = manifest_path.read_text(encoding="utf-8")
    return _load_described(source.folder, manifest, text, manifest_path, hash_file)


def _load_mpu6000_folder(folder: Path, serial: str | None, hash_file: FileHasher) -> LoadedRun:
    runs = find_mpu6000_runs(folder, complete=False)
    if serial not in runs:
        raise IngestError(f"no MPU-6000 files of serial '{serial}'", file=folder)
    files = runs[serial]
    procedure = check_complete(folder, serial, files)
    newest = max(p.stat().st_mtime for p in files.values())
    manifest = run_manifest(
        {
            "schema_version": 1,
            "unit": {"serial": serial, "model": "MPU-6000", "manufacturer": "InvenSense"},
            "run": {
                "started": datetime.fromtimestamp(newest, tz=UTC),
                "operator": "unknown",
                "procedure": procedure,
                "tolerance_profile": "mpu6000",
            },
            "format": {"kind": "mpu6000"},
            "segments": [{"label": label, "file": p.name} for label, p in files.items()],
        }
    )
    return _load_described(folder, manifest, None, None, hash_file)


def with_lab_site(manifest: RunManifest, source: str) -> RunManifest:
    """The manifest with the lab file's site when it gives neither a latitude nor a gravity
    model (the lab profile's [site], pipelines.lab.lab_site); the archived site says which
    file."""
    site = manifest.site
    if site.latitude_deg is not None or site.gravity_model is not None:
        return manifest
    try:
        lab = lab_site()
    except ValueError as exc:
        raise IngestError(str(exc), file=source, field="site") from None
    if lab is None:
        return manifest
    values, path = lab
    return dataclasses.replace(
        manifest, site=dataclasses.replace(site, **values, from_file=str(path))
    )


def _mpu6000_segments(folder: Path, manifest: RunManifest, source: str) -> list[SegmentSpec]:
    """Segments of an MPU-6000 run whose manifest leaves them to the file names."""
    serial = manifest.unit.serial
    files = find_mpu6000_runs(folder, complete=False).get(serial, {})
    if not files:
        raise IngestError(
            f"no MPU-6000 files of serial '{serial}' ({serial}_<axis>_<sense>.txt) in {folder}",
            file=source,
            field="segments",
        )
    check_complete(folder, serial, files)
    return [SegmentSpec(label=label, file=p.name) for label, p in files.items()]


def _load_described(
    folder: Path,
    manifest: RunManifest,
    text: str | None,
    manifest_path: Path | None,
    hash_file: FileHasher,
) -> LoadedRun:
    """Read the segments a manifest describes (real or synthesised)."""
    source = str(manifest_path or folder)
    check_segments(manifest, source, text or "")
    manifest = with_lab_site(manifest, source)
    if manifest.format.kind == "imutk":
        manifest = dataclasses.replace(manifest, format=imutk_format(manifest.format))
    kind = manifest.format.kind
    segments = manifest.segments or _mpu6000_segments(folder, manifest, source)
    reader = reader_for(kind)
    by_section = kind == "csv" and (
        manifest.format.section_column is not None or any(s.section for s in segments)
    )
    if by_section:
        reader = read_csv_sections  # type: ignore[assignment]

    root = folder.resolve()
    # file name -> whole-file recording, or {section: recording} when cut by a section column
    recordings: dict[str, Recording | dict[str, Recording]] = {}
    raw_files: list[RawFile] = []
    if manifest_path is not None:
        raw_files.append(
            RawFile(manifest_path, MANIFEST_NAME, *hash_file(manifest_path), "manifest")
        )

    out: dict[str, Recording] = {}
    findings: list[dict] = []
    hashed: set[str] = set()
    increasing: dict[int, bool] = {}  # id of a whole-file recording -> its t strictly increases
    checked: dict[str, Path] = {}  # file name -> its path, checked once (segments share files)
    for i, seg in enumerate(segments):
        names = seg.files
        for name in names:
            if name not in checked:
                checked[name] = data_file(folder, root, seg, i, name, source)
        paths = [checked[name] for name in names]
        if kind == "mpu6000":
            parsed = parse_file_name(paths[0].name)
            if parsed is not None and parsed[0] != manifest.unit.serial:
                raise IngestError(
                    f"file {seg.file!r} is of serial '{parsed[0]}', the manifest's unit is "
                    f"'{manifest.unit.serial}'",
                    file=source,
                    field=f"segments[{i}].file",
                )
        if len(names) == 2 and kind != "csv":
            raise IngestError(
                f"separate acc_file / gyr_file are read for format kind 'csv' only, not '{kind}'",
                file=source,
                field=f"segments[{i}].acc_file",
            )
        key = " + ".join(names)
        if key not in recordings:
            try:
                if len(names) == 2:
                    recordings[key] = read_csv_pair(paths[0], paths[1], manifest.format)
                else:
                    recordings[key] = reader(paths[0], manifest.format)
            except IngestError as exc:
                if exc.file is None:  # a reader's complaint about the manifest's format section
                    raise IngestError(exc.problem, file=source, field=exc.field) from None
                raise
            whole_file = recordings[key]
            for part in whole_file.values() if isinstance(whole_file, dict) else [whole_file]:
                check_readings(part, " + ".join(str(p) for p in paths))
                findings.extend(part.findings)
            for name, path in zip(names, paths, strict=True):
                if name not in hashed:
                    hashed.add(name)
                    raw_files.append(RawFile(path, name, *hash_file(path), kind))
        whole = recordings[key]
        if isinstance(whole, dict):
            whole = _section(whole, seg, i, source)
        if id(whole) not in increasing:  # once per file (or section), not per segment
            increasing[id(whole)] = whole.strictly_increasing()
        out[seg.label] = _cut(whole, seg, i, source, increasing[id(whole)])
        _check_range(out[seg.label], manifest, seg, source, paths)
    return LoadedRun(
        folder=folder,
        manifest=manifest,
        manifest_text=text,
        segments=out,
        raw_files=raw_files,
        verification_labels={s.label for s in segments if s.verification},
        findings=findings,
    )


def _check_range(
    rec: Recording, manifest: RunManifest, seg: SegmentSpec, source: str, paths: list[Path]
) -> None:
    """Refuse a segment whose readings reached the sensor's range (naming file, time, axis).

    The resolved gyro range goes into the run's settings (the integral method's own
    check and the archived settings use it).
    """
    gyro, acc = range_limits(manifest, source)
    hit = first_range_hit(rec, gyro, acc)
    if hit is not None:
        refuse_range_hit(hit, manifest, seg, paths)


def range_limits(manifest: RunManifest, source: str) -> tuple[float | None, float | None]:
    """The gyro (rad/s) and accelerometer (m/s^2) full scales of the run's unit (None: not
    known); the resolved gyro range goes into the run's settings (`_check_range`)."""
    settings = manifest.run.settings
    given = settings.get("gyro_range_dps")
    if given is not None and (
        isinstance(given, bool) or not isinstance(given, int | float) or given <= 0
    ):
        raise IngestError(
            f"expected a positive number (deg/s), got {given!r}",
            file=source,
            field="run.settings.gyro_range_dps",
        )
    gyro_dps, acc_g = sensor_ranges(manifest.unit, settings)
    if gyro_dps is not None and given is None:
        settings["gyro_range_dps"] = gyro_dps
    return (
        None if gyro_dps is None else gyro_dps * DEG,
        None if acc_g is None else acc_g * STANDARD_GRAVITY,
    )


def refuse_range_hit(
    hit: RangeHit, manifest: RunManifest, seg: SegmentSpec, paths: list[Path]
) -> NoReturn:
    """Raise the IngestError of a reading at the sensor's range: file, time, axis, what to do."""
    if hit.sensor == "gyr":
        what = f"gyro {hit.axis} reads {hit.value / DEG:.3f} deg/s"
        full = f"+-{hit.full_scale / DEG:g} deg/s"
        hint = "repeat the rotation slower"
    else:
        what = f"accelerometer {hit.axis} reads {hit.value / STANDARD_GRAVITY:.4f} g"
        full = f"+-{hit.full_scale / STANDARD_GRAVITY:g} g"
        hint = "repeat the segment with less acceleration (a slower start and stop)"
    raise IngestError(
        f"segment '{seg.label}': {what} at t = {hit.time:.3f} s, at the sensor's range "
        f"({full}, {manifest.unit.model}; set [unit] gyro_range_dps / acc_range_g if the "
        f"sensor was set to another range): the reading is clipped, the result would be "
        f"wrong; {hint}",
        file=" + ".join(str(p) for p in paths),
    )


def data_file(
    folder: Path, root: Path, seg: SegmentSpec, index: int, name: str, source: str
) -> Path:
    """The path of one of a segment's files, which must exist inside the run folder."""
    which = "file" if name == seg.file else ("acc_file" if name == seg.acc_file else "gyr_file")
    field_ = f"segments[{index}].{which}"
    path = folder / name
    if not path.resolve().is_relative_to(root):  # a symlink out of the run folder
        raise IngestError(f"{name!r} points outside the run folder", file=source, field=field_)
    if not path.is_file():
        raise IngestError(
            f"segment '{seg.label}': file {name!r} not found in {folder}",
            file=source,
            field=field_,
        )
    return path


def _section(
    sections: dict[str, Recording], seg: SegmentSpec, index: int, source: str
) -> Recording:
    """The rows of the segment's section (``section``, else its label)."""
    name = seg.section or seg.label
    if name not in sections:
        raise IngestError(
            f"segment '{seg.label}': section {name!r} is not in {seg.file}; its sections are "
            f"{', '.join(sections)}",
            file=source,
            field=f"segments[{index}].section",
        )
    return sections[name]


STILL_TURNING = 5.0 * DEG  # rad/s: a gyro this far from its reading at the segment's start


def check_window_end(
    seg: SegmentSpec,
    index: int,
    source: str,
    data_end: float,
    step: float,
    ends: Callable[[], tuple[np.ndarray, np.ndarray]],
) -> None:
    """Refuse a window that runs past the end of the data while the unit still turns
    there: the file was cut short mid-motion (a log that lost power), the turn would be
    silently incomplete. A window padded past the end of a file that ends at rest reads
    as before. (Not called for a rate plateau, a table_rate reference: it turns on
    purpose, its reference is the table's own rate, and a plateau cut short is a shorter
    record, which the record-time condition judges; nor for fewer than 20 samples.)

    data_end : the data's last time, s; step : the window's median time step, s;
    ends : the gyro's first and last ten rows of the window, (10, 3) rad/s each (read only
    when the window runs past the data's end).
    """
    if seg.end_s is None or seg.end_s <= data_end + 1.5 * max(step, 0.0):
        return
    head, tail = ends()
    moved = float(np.linalg.norm(np.median(tail, axis=0) - np.median(head, axis=0)))
    if moved > STILL_TURNING:
        raise IngestError(
            f"segment '{seg.label}': the window [{seg.start_s}, {seg.end_s}) s runs past the "
            f"end of the data ({' + '.join(seg.files)} ends at {data_end:.6g} s) while the "
            f"unit still turns there (gyro {moved / DEG:.1f} deg/s "
            "from its reading at the segment's start): the file was cut short",
            file=source,
            field=f"segments[{index}]",
        )


def empty_window(seg: SegmentSpec, index: int, source: str, t0: float, t1: float) -> IngestError:
    """The error of a segment whose window holds no samples of data spanning t0 .. t1 s."""
    return IngestError(
        f"segment '{seg.label}': the window [{seg.start_s}, {seg.end_s}) s holds no samples; "
        f"{' + '.join(seg.files)} spans {t0:.6g} .. {t1:.6g} s",
        file=source,
        field=f"segments[{index}]",
    )


def check_window_inside(
    seg: SegmentSpec, index: int, source: str, first: float, last: float
) -> None:
    """Refuse a window that lies more outside the record (times first .. last s) than
    inside it (a start 1e9 s before the file's first sample, a wrong time base): the
    manifest contradicts the file. A window padded a little past either end of the record
    reads as the record's part; a record of one time is not judged."""
    if not last > first:
        return
    start = first if seg.start_s is None else seg.start_s
    end = last if seg.end_s is None else seg.end_s
    outside = max(0.0, first - start) + max(0.0, end - last)
    inside = min(end, last) - max(start, first)
    if outside > max(inside, 0.0):
        raise IngestError(
            f"segment '{seg.label}': the window [{seg.start_s}, {seg.end_s}) s lies "
            f"{outside:.6g} s outside the record and {max(inside, 0.0):.6g} s inside it "
            f"({' + '.join(seg.files)} spans {first:.6g} .. {last:.6g} s); expected a "
            "window inside the record (the file's own time axis, s)",
            file=source,
            field=f"segments[{index}]",
        )


def _cut(
    whole: Recording, seg: SegmentSpec, index: int, source: str, increasing: bool = False
) -> Recording:
    """The segment's time window of a whole-file recording, labelled (`increasing`: its
    t strictly increases, see `Recording.window`)."""
    if seg.start_s is None and seg.end_s is None:
        return whole.with_label(seg.label)
    start = -float("inf") if seg.start_s is None else seg.start_s
    end = float("inf") if seg.end_s is None else seg.end_s
    if len(whole):
        check_window_inside(seg, index, source, float(whole.t[0]), float(whole.t[-1]))
    part = whole.window(start, end, label=seg.label, increasing=increasing)
    if len(part) == 0:
        raise empty_window(seg, index, source, whole.t[0], whole.t[-1])
    if len(part) >= 20 and "table_rate" not in part.reference:
        step = float(np.median(np.diff(part.t)))
        ends = lambda: (part.gyr[:10], part.gyr[-10:])  # noqa: E731
        check_window_end(seg, index, source, whole.t[-1], step, ends)
    where = f"{whole.source} t in [{seg.start_s}, {seg.end_s}) s"
    return dataclasses.replace(part, label=seg.label, source=where)
