"""The `calib` command's shared parts: the Typer app, consoles, common options, output helpers.

`pipelines.cli` defines the run commands and imports `pipelines.commands`; the command
modules import these from here, never from `pipelines.cli`, so imports go one way.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import json
import math
import os
import signal
import sys
from collections.abc import Callable, Iterator
from datetime import date, datetime
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

import pipelines  # noqa: F401 - sets the no-telemetry environment before Prefect loads


def _tidy_help(params: list[Any]) -> None:
    """Metavars for people: none on a flag (typer shows ``<bool>``), the option's name
    (``--archive ARCHIVE``) or its choices on the others, the argument's name in capitals."""
    from typer.core import TyperArgument, TyperOption

    for p in params:
        if p.metavar is not None:
            continue
        if isinstance(p, TyperOption):
            if p.is_flag or p.is_bool_flag:
                p.metavar = ""
            elif p.type_descriptor.is_choice:
                p.metavar = p.display_type(None).strip("<>")
            else:
                p.metavar = max(p.opts, key=len).lstrip("-").upper().replace("-", "_")
        elif isinstance(p, TyperArgument):
            p.metavar = (p.name or "").upper()
            p.display_type_rich = lambda ctx: None  # the name says it; no <str> column


def _plain_values(params: list[Any]) -> None:
    """Values that already have their parameter's type taken as given, without pydantic.

    Typer (0.2x) converts every value through a pydantic TypeAdapter built on first use,
    even the default of an option not given, and importing pydantic for that is a large
    part of a read-only command's start. Each parameter without a parser gets `_given`
    instead: a text, flag or choice value that already has the type is returned as it is
    (what the adapter returns too); no value (None) stays None as before; any other value
    goes to typer's own conversion, so pydantic loads only when a value needs it.
    """
    try:
        given = _given()
    except ImportError:  # a typer without pydantic conversion
        return
    for p in params:
        described = getattr(p, "type_descriptor", None)
        if (
            described is not None
            and getattr(p, "_runtime_param", False) is None
            and described.parameter_info.parser is None
            and described.file_annotation is None
        ):
            try:
                p._runtime_param = given(described.parameter_info, described.annotation)
            except TypeError:  # another typer's RuntimeParam: its own conversion throughout
                return


@functools.cache
def _given() -> type:
    """`_plain_values`' conversion: a typer RuntimeParam (made once)."""
    from enum import Enum

    from typer._coercion import RuntimeParam, build_runtime_param

    class Given(RuntimeParam):
        def _coerce_value(self, value: Any, param: Any, ctx: Any) -> Any:  # noqa: ANN401
            kind = self.annotation
            try:
                plain = kind in (str, bool) or issubclass(kind, Enum)
            except TypeError:  # not a class: list[...], a union
                plain = False
            if plain and isinstance(value, kind):
                return value
            typers = build_runtime_param(param.type_descriptor)
            return typers._coerce_value(value, param=param, ctx=ctx)

    return Given


class CalibGroup(typer.core.TyperGroup):
    """Typer's group with `_tidy_help` and `_plain_values` applied to its own and its
    commands' parameters."""

    def get_params(self, ctx):  # noqa: ANN001, ANN201 - click's signature
        params = super().get_params(ctx)
        _tidy_help(params)
        _plain_values(params)
        return params

    def get_command(self, ctx, cmd_name):  # noqa: ANN001, ANN201 - click's signature
        cmd = super().get_command(ctx, cmd_name)
        if cmd is not None:
            params = cmd.get_params(ctx)
            _tidy_help(params)
            _plain_values(params)
        return cmd


def sub_app(help: str) -> typer.Typer:  # noqa: A002 - typer's name
    """A group of subcommands (`calib query ...`) with the same help conventions."""
    return CalibTyper(cls=CalibGroup, no_args_is_help=True, help=help)


class CalibTyper(typer.Typer):
    """Typer's app that builds only the command it runs.

    Typer builds every command and group (their parameters, from the signatures) before
    it parses a word; `calib history` needs one of them. When the first word after the
    global flags names a command, only that command is built; `calib --version` builds
    none. Everything else (no command, --help, a word that is no command, shell
    completion) gets the whole app, so help, suggestions and completion see every command.
    """

    def command(self, *args: Any, **kwargs: Any) -> Callable[[Callable], Callable]:
        """Typer's command, its help the docstring with each paragraph's lines joined (typer
        keeps the source's line breaks, which a terminal then folds mid-sentence), and its
        one-line help in `calib --help` the first paragraph."""
        register = super().command(*args, **kwargs)

        def wrap(func: Callable) -> Callable:
            done = register(func)
            info = self.registered_commands[-1]
            paragraphs = reflowed(inspect.getdoc(func) or "")
            if kwargs.get("help") is None:
                info.help = "\n\n".join(paragraphs) or None
            if kwargs.get("short_help") is None:
                info.short_help = paragraphs[0] if paragraphs else None
            return done

        return wrap

    def __call__(self, *args: Any, **kwargs: Any) -> Any:  # noqa: ANN401 - typer's
        argv = kwargs.get("args", args[0] if args else None)
        words = list(sys.argv[1:] if argv is None else argv)
        keep = None if _completing() else _invoked(self, words)
        if keep is None:
            return super().__call__(*args, **kwargs)
        every = self.registered_commands, self.registered_groups
        self.registered_commands = [c for c in every[0] if _name(c) in keep]
        self.registered_groups = [g for g in every[1] if _name(g) in keep]
        try:
            return super().__call__(*args, **kwargs)
        finally:
            self.registered_commands, self.registered_groups = every


def reflowed(text: str) -> list[str]:
    """The paragraphs of a docstring, each one line; a paragraph of list items ("- ...")
    or indented lines keeps its line breaks."""
    out = []
    for para in text.strip().split("\n\n"):
        lines = para.splitlines()
        listed = any(line.startswith(("- ", "* ", " ")) for line in lines)
        out.append(para if listed else " ".join(line.strip() for line in lines))
    return [p for p in out if p.strip()]


def _name(info: Any) -> str:  # noqa: ANN401 - a typer CommandInfo or TyperInfo
    """A registered command's or group's name on the command line."""
    return info.name or info.callback.__name__.replace("_", "-")


def _completing() -> bool:
    """Is the shell asking for completions (typer's ``_CALIB_COMPLETE``)?"""
    return any(k.startswith("_") and k.endswith("_COMPLETE") for k in os.environ)


def _invoked(app_: typer.Typer, words: list[str]) -> set[str] | None:
    """The names to build for `words`: the command the first word after the global flags
    names; none for ``--version`` alone; None (all) otherwise."""
    first = next((i for i, w in enumerate(words) if not w.startswith("-")), len(words))
    flags, rest = words[:first], words[first:]
    if any(f in ("--help", "--install-completion", "--show-completion") for f in flags):
        return None
    if not rest:
        return set() if "--version" in flags else None
    names = {_name(i) for i in [*app_.registered_commands, *app_.registered_groups]}
    return {rest[0]} if rest[0] in names else None


app = CalibTyper(cls=CalibGroup, no_args_is_help=True, help="IMU calibration pipeline and archive.")

# `calib --help` lists the commands under these headings, by task (`group_commands`).
PANELS = {
    "Process": ("process", "reprocess", "centrifuge", "apply", "thermal", "impact"),
    "Inspect": ("inspect", "show", "history", "repeatability", "procedures"),
    "Query": ("query", "due", "trend", "fleet"),
    "Report": ("report", "verify-certificate", "navfit", "serve", "serve-user", "validate"),
    "Export": ("export",),
    "Admin": ("verify", "checkpoint", "audit", "approve", "keygen", "backup", "restore"),
}


def group_commands() -> None:
    """Put every registered command and group under its `PANELS` heading.

    Raises
    ------
    LookupError : a command that no heading lists (add it to PANELS).
    """
    where = {name: panel for panel, names in PANELS.items() for name in names}
    for info in [*app.registered_commands, *app.registered_groups]:
        name = _name(info)
        if name not in where:
            raise LookupError(f"calib {name}: no help panel; add it to cli_shared.PANELS")
        info.rich_help_panel = where[name]


def _version(show: bool) -> None:
    if show:
        from calib_core import __version__  # no numpy: calib_core/__init__ holds the version only

        sys.stdout.write(f"calib {__version__}\n")
        raise typer.Exit()


# soft_wrap: printed text is never wrapped or cut by rich (a path stays one line the
# terminal wraps, so it can be copied whole); tables still fit the width.
out = Console(soft_wrap=True)
err = Console(stderr=True, soft_wrap=True)
# Display settings of this invocation (the global options of `calib`).
DISPLAY = {"wide": False}

ArchiveOpt = Annotated[
    str | None,
    typer.Option(
        "--archive",
        envvar="CALIB_ARCHIVE",
        help="Archive directory or SQLAlchemy URL (default ./calib-archive).",
    ),
]
# The batch options of the commands that solve archived runs again (reprocess, verify).
RunnerOpt = Annotated[str, typer.Option("--runner", help="local (threads), process or dask.")]
WorkersOpt = Annotated[
    int | None, typer.Option("--workers", help="Runs in parallel (default: the cores).")
]
SchedulerOpt = Annotated[
    str | None, typer.Option("--scheduler", help="Dask scheduler, tcp://host:8786.")
]
ProgressOpt = Annotated[
    bool | None, typer.Option("--progress/--no-progress", help="Progress bar on stderr.")
]
JsonOpt = Annotated[
    bool, typer.Option("--json", help="Print the JSON document (for scripts) instead of text.")
]
# What was current at a time: the queries and exports that choose a calibration or model.
AtOpt = Annotated[
    str | None,
    typer.Option("--at", help="As of this date (the whole UTC day) or ISO date-time with zone."),
]
RevisionOpt = Annotated[
    int | None, typer.Option("--revision", help="Calibration revision (default: the current one).")
]
# The autopilot files' options (pipelines.autopilot): `calib export` and `calib thermal export`.
DeviceIdOpt = Annotated[
    int | None,
    typer.Option(
        "--device-id",
        help="PX4 device id of the sensor (its CAL_ACC0_ID / CAL_GYRO0_ID); default: the ids "
        "the run's ULog recorded, else refused.",
    ),
]
RotationOpt = Annotated[
    str | None,
    typer.Option(
        "--rotation",
        help="The firmware's rotation of the calibrated axes, by its own name (PX4 "
        "SENS_BOARD_ROT / ArduPilot AHRS_ORIENTATION enumeration, e.g. YAW_90); default NONE.",
    ),
]
VehicleIdOpt = Annotated[
    int, typer.Option("--vehicle-id", help="PX4 file: the vehicle's MAVLink system id.")
]


@app.callback()
def _main(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version."),
    ] = False,
    verbose: Annotated[
        bool,
        typer.Option(
            "--verbose", "-v", help="Prefect's and the pipeline's progress logs on stderr."
        ),
    ] = False,
    wide: Annotated[
        bool,
        typer.Option(
            "--wide",
            help="Tables with every column, wider than the terminal if need be (default: "
            "the columns that fit, the others named below the table).",
        ),
    ] = False,
) -> None:
    """IMU calibration pipeline and archive."""
    quiet_logs(verbose)
    DISPLAY["wide"] = wide
    # A full disk, a read-only archive, a missing permission: one line saying which
    # file and what to do instead of a traceback (typer has set its own hook by now).
    previous = sys.excepthook

    def explain(kind, exc, tb) -> None:  # noqa: ANN001 - sys.excepthook's signature
        from storage.write_failures import describe

        opened = OPENED.get("archive")
        problem = describe(exc, opened.url if opened else os.environ.get("CALIB_ARCHIVE"))
        if problem is None:
            previous(kind, exc, tb)
        else:
            err.print(f"[red]error:[/red] {problem}")

    sys.excepthook = explain


def quiet_logs(verbose: bool) -> None:
    """Prefect's logs at warning level unless `verbose` (its INFO lines of every flow and
    task run are progress, which the progress bar and the result table already show).

    Set in the environment before Prefect is imported (commands import it when they
    need it), so the temporary API server it starts gets them too. Without --verbose
    that server reports only critical errors: the ones it logs when calib ends it while
    it still records task-run events (``Error flushing N events`` and a traceback) are
    about Prefect's own run history of a server that ends with calib, never about a run's
    outcome or the archive. A setting made by the user in the environment wins.
    """
    import logging

    if verbose:
        os.environ["PREFECT_LOGGING_LEVEL"] = "INFO"
        logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
        return
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    os.environ.setdefault("PREFECT_SERVER_LOGGING_LEVEL", "CRITICAL")


# The archive this invocation opened: named by the error hook of `_main`.
OPENED: dict[str, Any] = {}


def open_archive(arg: str | None):
    from storage.db import open_archive as open_

    OPENED["archive"] = archive = open_(arg)
    return archive


def open_run(archive_arg: str | None, run_id: str):  # noqa: ANN201 - (Archive, str)
    """The archive and the full id of the run that `run_id` names (the id or a unique
    prefix, as git takes them); a clear error and exit 2 otherwise."""
    from storage import queries

    arch = open_archive(archive_arg)
    with fail_on(LookupError, ValueError):
        return arch, queries.full_run_id(arch, run_id)


def fail(message: str) -> None:
    """Print the error and exit 2; the message is text (a "[customer]" in it stays)."""
    from rich.markup import escape

    err.print(f"[red]error:[/red] {escape(message)}")
    raise typer.Exit(2)


@contextlib.contextmanager
def fail_on(*errors: type[Exception]) -> Iterator[None]:
    """An error of one of these kinds raised inside the block: its message printed as
    `fail` prints it, exit 2."""
    try:
        yield
    except errors as exc:
        fail(str(exc))


def at_instant(text: str | None, option: str = "--at") -> datetime | None:
    """The instant a date option of the CLI names, by `storage.queries.as_instant`'s rule.

    A bare date (YYYY-MM-DD) is the end of that UTC day; a date and time needs a zone
    (``+00:00`` or ``Z``). Anything else exits 2 naming `option`, what was expected and
    what was found. None stays None (now).
    """
    from storage.queries import as_instant

    with fail_on(ValueError):
        return as_instant(text, option, end_of_day=True)
    return None  # not reached: fail_on exits


def plain(value: Any) -> Any:
    """A JSON-ready value: dates and times ISO 8601 (``isoformat``), None for NaT and for
    NaN or an infinity (JSON has neither), NumPy scalars as Python numbers, dicts and
    lists value by value."""
    import pandas as pd

    if value is None or value is pd.NaT:
        return None
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, datetime | date | pd.Timestamp):
        return value.isoformat()
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if hasattr(value, "item"):  # numpy scalars
        return plain(value.item())
    return value


def frame_records(df: Any) -> list[dict[str, Any]]:
    """A DataFrame's rows as JSON-ready dicts (`plain`): the CLI's one JSON form of a table."""
    return [plain(r) for r in df.astype(object).to_dict(orient="records")]


def print_json(doc: Any) -> None:
    sys.stdout.write(json.dumps(doc, indent=2, default=str) + "\n")


def is_id_column(name: str) -> bool:
    """Columns of identifiers (run ids, serials, check names): never wrapped or cut in a
    table."""
    return name in ("run_id", "serial", "run", "check") or name.endswith("_id")


def print_table(
    title: str,
    columns: list[str],
    rows: list[list[str]],
    facts: str | None = None,
    whole: tuple[str, ...] = (),
) -> None:
    """Print `rows` (strings, rich markup allowed) under `columns` to fit the terminal.

    Identifier columns (`is_id_column`) keep their values whole on one line; the other
    cells wrap (long words fold) instead of being cut. When even so the table is wider
    than the terminal, columns are left out from the right and named on stderr, unless
    ``calib --wide``, which prints them all at the width they need. `facts` (text
    common to every row) are printed above the table; `whole` names more columns whose
    values stay on one line (dates).
    """
    shown = list(columns)
    while True:
        candidate = Table(title=title)
        for name in shown:
            # "needs review" on one line
            keep = is_id_column(name) or name == "verdict" or name in whole
            candidate.add_column(name.replace("_", " "), no_wrap=keep, overflow="fold")
        for row in rows:
            candidate.add_row(*(row[columns.index(n)] for n in shown))
        # minimum: every cell's longest word on one line, a no-wrap cell whole;
        # maximum: no cell wrapped
        need = candidate.__rich_measure__(out, out.options.update_width(10_000))
        if DISPLAY["wide"] or _minimum_width(candidate) <= out.width or len(shown) <= 2:
            break
        shown.pop()
    if not DISPLAY["wide"]:
        _fit(candidate, out.width)
    if facts:
        from rich.text import Text

        candidate.caption = Text(facts)
    if DISPLAY["wide"]:
        # Console.print(width=) only narrows, and setting out.width would pin it for every
        # later print: a console of the width the table needs, on the same stream.
        wide = Console(file=out.file, soft_wrap=True, width=max(out.width, need.maximum))
        wide.print(candidate)
    else:
        out.print(candidate)
    if len(shown) < len(columns):
        hidden = ", ".join(c for c in columns if c not in shown)
        sys.stdout.flush()
        err.print(f"(not shown at this width: {hidden}; calib --wide shows every column)")


def _width_ranges(table: Table) -> list[tuple[int, int]]:
    """(narrowest, widest) of each column with its padding: the narrowest folds no word
    and wraps no no-wrap cell (an id, a verdict), which rich's own minimum leaves out."""
    options = out.options.update_width(10_000)
    ranges = []
    for column in table.columns:
        m = table._measure_column(out, options, column)
        ranges.append((m.maximum if column.no_wrap else m.minimum, m.maximum))
    return ranges


def _minimum_width(table: Table) -> int:
    """The narrowest `table` can be with no word folded and no no-wrap cell wrapped."""
    return table._extra_width + sum(lo for lo, _ in _width_ranges(table))


def _fit(table: Table, width: int) -> None:
    """Fix the columns' widths so that `table` is `width` wide and no column is narrower
    than its longest word: each starts at its narrowest and gets a share of the room left
    by what it could use more. (Rich shrinks the widest columns first, below their
    longest word: a date folded as "2027-11-2" / "8".)"""
    ranges = _width_ranges(table)
    room = width - table._extra_width - sum(lo for lo, _ in ranges)
    spare = sum(hi - lo for lo, hi in ranges)
    if room < 0 or spare <= room:
        return  # too narrow for any fit (rich folds), or wide enough as it is
    widths = [lo + (hi - lo) * room // spare for lo, hi in ranges]
    for i in sorted(range(len(widths)), key=lambda i: widths[i] - ranges[i][1]):
        if sum(widths) < width - table._extra_width and widths[i] < ranges[i][1]:
            widths[i] += 1  # what the rounding left, to the columns furthest from their widest
    for column, w in zip(table.columns, widths, strict=True):
        column.width = max(1, w - table._get_padding_width(column._index))


def print_frame(df, title: str, whole: tuple[str, ...] = ()) -> None:
    """A DataFrame as a table that fits the terminal (`print_table`); columns with one
    value in every row (the serial and run of a run's parameters) are said once above it.
    The row's identity (serial, run id) and its verdict come first: a narrow terminal
    leaves out columns from the right; `whole` as in `print_table`."""
    first = [c for c in df.columns if is_id_column(str(c))] + [
        c for c in df.columns if c == "verdict"
    ]
    df = df[first + [c for c in df.columns if c not in first]]
    columns = [str(c) for c in df.columns]
    rows = [[cell(v) for v in row] for row in df.itertuples(index=False)]
    same = [c for i, c in enumerate(columns) if len(rows) > 1 and len({r[i] for r in rows}) == 1]
    if len(columns) - len(same) < 2:
        same = []
    facts = "; ".join(f"{c.replace('_', ' ')}: {rows[0][columns.index(c)] or '-'}" for c in same)
    keep = [i for i, c in enumerate(columns) if c not in same]
    shown = [columns[i] for i in keep]
    print_table(title, shown, [[r[i] for i in keep] for r in rows], facts, whole)


def cell(value: Any) -> str:
    """A value as a table cell, escaped (a value is data, never rich markup: "[site]"
    stays): floats to 6 significant digits (--json and csv keep every digit), NaN and
    None empty, instants in UTC to the second, booleans yes / no."""
    import math
    from datetime import UTC, datetime

    from rich.markup import escape

    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, datetime):
        if value.tzinfo is None:  # the archive's naive instants are UTC
            return f"{value:%Y-%m-%d %H:%M:%S}"
        return f"{value.astimezone(UTC):%Y-%m-%d %H:%M:%S} UTC"
    return escape(str(value))


def print_facts(facts: dict[str, Any], title: str, paths: tuple[str, ...] = ()) -> None:
    """A flat dict as a two-column table (what, value); long values wrap, never cut.

    The values of the keys in `paths` (file paths) follow the table one per line, whole
    (``output: /the/path``): a path wrapped inside a cell cannot be copied.
    """
    table = Table(title=title, show_header=False)
    table.add_column("what", style="bold", no_wrap=True)
    table.add_column("value", overflow="fold")
    for key, value in facts.items():
        if key in paths:
            continue
        if isinstance(value, list):
            value = ", ".join(map(cell, value)) or None
        table.add_row(_label(key), "-" if value is None else cell(value))
    out.print(table)
    for key in paths:
        if facts.get(key) is not None:
            out.print(f"{_label(key)}: {facts[key]}", soft_wrap=True, markup=False, highlight=False)


def _label(key: str) -> str:
    """A JSON key for people: ``calibration_temperature_c`` -> ``calibration temperature (°C)``."""
    for suffix, unit in (("_c", "°C"), ("_s", "s"), ("_days", "days")):
        if key.endswith(suffix):
            return f"{key[: -len(suffix)].replace('_', ' ')} ({unit})"
    return key.replace("_", " ")


def warn(message: str) -> None:
    """A warning on stderr (markup in `message` is not interpreted)."""
    from rich.markup import escape

    err.print(f"[yellow]warning:[/yellow] {escape(message)}", soft_wrap=True)


@contextlib.contextmanager
def progress_bar(show: bool) -> Iterator[Callable[[int, int, dict], None]]:
    """A callback(done, total, outcome) drawing a progress bar on stderr (stdout stays data)."""
    if not show:
        yield lambda done, total, outcome: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn

    columns = ("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn())
    with Progress(*columns, TimeElapsedColumn(), console=err) as bar:
        task = bar.add_task("runs", total=None)

        def advance(done: int, total: int, outcome: dict) -> None:
            failed = " (failed)" if outcome["status"] == "failed" else ""
            label = outcome["serial"] or Path(outcome["source"]).name
            bar.update(task, completed=done, total=total, description=f"{label}{failed}")

        yield advance


@contextlib.contextmanager
def interrupt_exits_at_once() -> Iterator[Callable[[int, int, dict], None]]:
    """Ctrl-C during a batch on Prefect's temporary local API: say where it stood, exit 130.

    The same Ctrl-C stops the temporary API server (it is in the terminal's process
    group), after which Prefect spends a minute or more retrying its reports to
    it. Exiting at once is
    as safe as a kill at that moment, which the archive is built and tested for
    (tests/test_crash.py): each run is archived whole or not at all, and running
    the same command again skips the archived runs as duplicates. With a
    configured PREFECT_API_URL the server lives on, and Prefect's own handling
    (the flow run marked crashed) is kept.

    Yields a progress callback(done, total, outcome) that counts finished runs.
    """
    from prefect.settings import PREFECT_API_URL

    seen = {"done": 0, "total": 0}

    def count(done: int, total: int, _outcome: dict) -> None:
        seen.update(done=done, total=total)

    if PREFECT_API_URL.value():
        yield count
        return

    def stop(_signum: int, _frame: object) -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut this short
        from pipelines.flows import stop_temporary_api
        from pipelines.runners import kill_all_workers

        kill_all_workers()
        stop_temporary_api()
        err.print(
            f"\n[yellow]interrupted[/yellow] after {seen['done']} of {seen['total'] or '?'} "
            "run(s); runs in progress are not archived. Run the same command again to go on "
            "(archived runs are skipped as duplicates)."
        )
        os._exit(130)

    previous = signal.signal(signal.SIGINT, stop)
    try:
        yield count
    except BaseException:
        signal.signal(signal.SIGINT, previous)
        raise
    # The batch is over and every run archived: a Ctrl-C while the results are printed or
    # while Prefect stops its temporary server at exit only ends calib (no traceback).
    signal.signal(signal.SIGINT, _quiet_exit)


def _quiet_exit(_signum: int, _frame: object) -> None:
    """SIGINT after a finished batch: stop Prefect's temporary server, exit 130 at once."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from pipelines.flows import stop_temporary_api

    stop_temporary_api()
    os._exit(130)


@contextlib.contextmanager
def flow_batch_console(show: bool) -> Iterator[None]:
    """Around a batch flow run from the CLI: its progress bar (`show`), Ctrl-C handling
    (`interrupt_exits_at_once`) and the settings of Prefect's temporary local API."""
    from pipelines.flows import local_batch_settings, report_progress

    with progress_bar(show) as draw, interrupt_exits_at_once() as count, local_batch_settings():

        def on_progress(done: int, total: int, outcome: dict) -> None:
            draw(done, total, outcome)
            count(done, total, outcome)

        with report_progress(on_progress):
            yield
