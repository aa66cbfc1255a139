"""`calib --help` for people: commands grouped by task, sensible metavars, --version, shell
completion, and no Prefect log lines or tracebacks on a normal batch."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from calib_core import __version__
from pipelines.cli import app
from pipelines.cli_shared import PANELS

ROOT = Path(__file__).resolve().parents[1]
RUNNER = CliRunner()
WIDE = {"COLUMNS": "200", "NO_COLOR": "1"}


def _help(*words: str) -> str:
    done = RUNNER.invoke(app, [*words, "--help"], env=WIDE)
    assert done.exit_code == 0, done.output
    return done.output


def _commands(*words: str) -> list[str]:
    """The subcommand names `calib WORDS --help` lists."""
    return re.findall(r"^│ (\w[\w-]*)\s{2,}", _help(*words).split("─ Commands", 1)[-1], re.M)


def test_top_level_help_groups_every_command_by_task() -> None:
    text = _help()
    headings = re.findall(r"╭─ (\w+) ─", text)
    assert headings[0] == "Options" and set(headings[1:]) == set(PANELS)
    listed = {name for names in PANELS.values() for name in names}
    for panel, names in PANELS.items():
        block = text.split(f"╭─ {panel} ─", 1)[1].split("╰", 1)[0]
        assert sorted(re.findall(r"^│ (\w[\w-]*)\s{2,}", block, re.M)) == sorted(names)
    # every command typer knows sits under a heading (group_commands refuses others)
    known = {i.name or i.callback.__name__ for i in app.registered_commands}
    assert known | {g.name for g in app.registered_groups} == listed


@pytest.mark.parametrize(
    "words",
    [
        (),
        *[(c,) for names in PANELS.values() for c in names],
        ("query", "latest"),
        ("query", "lineage"),
        ("thermal", "fit"),
        ("thermal", "export"),
    ],
    ids=" ".join,
)
def test_no_typer_type_placeholders_in_help(words: tuple[str, ...]) -> None:
    text = _help(*words)
    assert "<bool>" not in text and "<str>" not in text and "<int>" not in text, text
    assert "<list[" not in text and "<Path>" not in text, text


def test_flags_have_no_metavar_and_options_are_named() -> None:
    text = _help("process")
    assert re.search(r"--json\s{2,}Print the JSON document", text), text
    assert re.search(r"--archive\s+ARCHIVE\s", text), text
    assert "PATHS" in text
    assert re.search(r"--format\s+table\|csv\|json\s", _help("query", "latest"))


def test_version() -> None:
    done = RUNNER.invoke(app, ["--version"])
    assert done.exit_code == 0 and done.output == f"calib {__version__}\n"


@pytest.mark.slow
def test_shell_completion_of_commands(monkeypatch: pytest.MonkeyPatch) -> None:
    # The shell named on the command line, not the one that started the tests (Typer
    # otherwise asks shellingham, and a run started from `sh` gets "Shell sh not supported").
    monkeypatch.setenv("_TYPER_COMPLETE_TEST_DISABLE_SHELL_DETECTION", "1")
    env = {
        **os.environ,
        "_CALIB_COMPLETE": "complete_bash",
        "COMP_WORDS": "calib query l",
        "COMP_CWORD": "2",
        "PYTHONPATH": str(ROOT),
    }
    code = "from pipelines.cli import app; app(prog_name='calib')"
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert done.stdout.split() == ["latest", "lineage", "lapsed"], done.stderr
    shown = RUNNER.invoke(app, ["--show-completion", "bash"], prog_name="calib")
    assert "_CALIB_COMPLETE=complete_bash" in shown.output


def test_quiet_logs_defaults_and_verbose(monkeypatch: pytest.MonkeyPatch) -> None:
    from pipelines.cli_shared import quiet_logs

    for name in ("PREFECT_LOGGING_LEVEL", "PREFECT_SERVER_LOGGING_LEVEL"):
        monkeypatch.delenv(name, raising=False)
    quiet_logs(False)
    assert os.environ["PREFECT_LOGGING_LEVEL"] == "WARNING"
    assert os.environ["PREFECT_SERVER_LOGGING_LEVEL"] == "CRITICAL"
    monkeypatch.setenv("PREFECT_LOGGING_LEVEL", "DEBUG")  # the user's own setting wins
    quiet_logs(False)
    assert os.environ["PREFECT_LOGGING_LEVEL"] == "DEBUG"
    quiet_logs(True)
    assert os.environ["PREFECT_LOGGING_LEVEL"] == "INFO"


@pytest.mark.e2e
def test_a_prefect_batch_prints_no_logs_or_tracebacks(tmp_path: Path) -> None:
    """A real flow run on Prefect's temporary server: stderr stays empty (no INFO lines of
    the flow, its tasks or the server, no traceback at the end)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_LOGGING")}
    env.pop("PREFECT_API_URL", None)
    env.update(PYTHONPATH=str(ROOT), DO_NOT_TRACK="1", PREFECT_SERVER_ANALYTICS_ENABLED="false")
    sample = ROOT / "data_samples" / "mpu6000_MPU0001"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "pipelines.cli",
            "process",
            str(sample),
            "--flow",
            "--archive",
            str(tmp_path / "a"),
            "--no-progress",
            "--json",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert done.stderr == "", done.stderr


@pytest.mark.e2e
def test_ctrl_c_after_a_finished_batch_ends_without_a_traceback() -> None:
    """After the batch (the table printed, Prefect stopping its temporary server), Ctrl-C
    ends calib with 130 and nothing on stderr (a KeyboardInterrupt traceback before)."""
    code = (
        "import os, signal, time\n"
        "from pipelines.cli_shared import interrupt_exits_at_once\n"
        "with interrupt_exits_at_once():\n"
        "    pass\n"
        "os.kill(os.getpid(), signal.SIGINT)\n"
        "time.sleep(5)\n"
        "print('not interrupted')\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    env.update(PYTHONPATH=str(ROOT), DO_NOT_TRACK="1", PREFECT_SERVER_ANALYTICS_ENABLED="false")
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 130 and done.stderr == "" and done.stdout == "", done.stderr


def test_each_command_is_one_line_in_a_wide_listing() -> None:
    """A command's short help is its docstring's first paragraph in one line: at 400
    columns no command's description breaks mid-sentence onto a second line."""
    done = RUNNER.invoke(app, ["--help"], env={"COLUMNS": "400", "NO_COLOR": "1"})
    assert done.exit_code == 0, done.output
    rows = [line for line in done.output.splitlines() if line.startswith("│ ")]
    continued = [line.strip("│ ") for line in rows if line.startswith("│" + " " * 8)]
    assert continued == [], continued
