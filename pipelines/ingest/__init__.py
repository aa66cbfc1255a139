"""Ingest: from a lab's raw files (and run manifest) to Recordings in SI units.

Start with :func:`discover_runs` (which runs do these paths hold?) and
:func:`load_run` (read one). Every input problem is an :class:`IngestError`
naming the file, line or manifest field.
"""

from pipelines.ingest.csv_reader import read_csv
from pipelines.ingest.data_format import FormatSpec
from pipelines.ingest.errors import IngestError
from pipelines.ingest.manifest import RunManifest, SegmentSpec, load_manifest
from pipelines.ingest.mpu6000 import find_mpu6000_runs, read_mpu6000_file
from pipelines.ingest.readers import register_reader
from pipelines.ingest.run_loader import (
    LoadedRun,
    RawFile,
    RunSource,
    discover_runs,
    load_run,
    read_run,
)

__all__ = [
    "FormatSpec",
    "IngestError",
    "LoadedRun",
    "RawFile",
    "RunManifest",
    "RunSource",
    "SegmentSpec",
    "discover_runs",
    "find_mpu6000_runs",
    "load_manifest",
    "load_run",
    "read_csv",
    "read_mpu6000_file",
    "read_run",
    "register_reader",
]
