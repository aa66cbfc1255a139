"""Every `calib` subcommand at an 80-column terminal: no run id and no path is cut.

One archive of the samples in data_samples/ (in-process runs, the thermal campaign
fitted), then every subcommand's human output (not --json) at COLUMNS=80. In each:
no ellipsis ('…': rich cut a cell), every run-id-like token a whole id of the
archive, every absolute path token a file or folder that exists (a path cut or
wrapped mid-way is a prefix that does not).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from pipelines import cli_shared
from pipelines.cli import app

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "data_samples"
RUN_ID = re.compile(r"\bR[0-9a-f]{6,}")
ABS_PATH = re.compile(r"(?:(?<=[\s'\"])|^)/(?:[\w.+=@-]+/)+[\w.+=@-]+", re.M)


def _invoke(*args: str) -> tuple[int, str]:
    done = CliRunner().invoke(app, list(args))
    return done.exit_code, done.stdout + done.stderr


@pytest.fixture(autouse=True)
def _eighty_columns(monkeypatch: pytest.MonkeyPatch) -> None:
    for console in (cli_shared.out, cli_shared.err):
        monkeypatch.setattr(console, "width", 80)
    monkeypatch.setitem(cli_shared.DISPLAY, "wide", False)


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The samples archived in this process (up to 4 runs per call: no Prefect)."""
    tmp = tmp_path_factory.mktemp("width")
    arch = str(tmp / "archive")
    for console in (cli_shared.out, cli_shared.err):
        console.width = 80
    outputs = []
    for group in (
        ["mpu6000_MPU0001", "csv_IMU-2026-0042"],
        ["history_IMU-R-0003"],
        ["thermal_IMU-T-0007"],
    ):
        code, text = _invoke(
            "process", *(str(SAMPLES / g) for g in group), "--archive", arch, "--no-progress"
        )
        assert code in (0, 1), text
        outputs.append(text)
    code, text = _invoke("thermal", "fit", "IMU-T-0007", "--archive", arch)
    assert code == 0, text
    outputs.append(text)
    done = CliRunner().invoke(app, ["query", "units", "--archive", arch, "--format", "json"])
    ids = {r["run_id"] for r in json.loads(done.stdout)}
    centrifuge = _centrifuge_run(tmp / "centrifuge")
    _unsigned_document(tmp)
    return {"tmp": tmp, "archive": arch, "ids": ids, "outputs": outputs, "centrifuge": centrifuge}


def _unsigned_document(tmp: Path) -> None:
    """An XML document without a signature and a self-signed certificate, for
    `calib verify-certificate` (which says NOT VALID and exits 1)."""
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "width test")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(1)
        .not_valid_before(now)
        .not_valid_after(now + datetime.timedelta(days=1))
        .sign(key, hashes.SHA256())
    )
    (tmp / "lab-cert.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (tmp / "unsigned.xml").write_text("<dcc/>\n")


def _centrifuge_run(folder: Path) -> Path:
    from calib_core.simulate.centrifuge import CentrifugeSchedule, simulate_centrifuge
    from calib_testing.run_writers import write_centrifuge_run

    truth = {
        "x": {"const": 0.2, "a_x": 1.5e-3},
        "y": {"const": -0.25, "a_y": 1.2e-3},
        "z": {"const": 0.3, "a_z": -1e-3},
    }
    short = CentrifugeSchedule(
        sample_rate=50.0, zero_duration=4.0, one_g_duration=20.0, step_duration=4.0
    )
    sim = simulate_centrifuge(truth, rng=np.random.default_rng(3), schedule=short)
    manifest = {
        "unit": {"serial": "HG-7", "model": "MEMS-HG", "manufacturer": "ACME"},
        "run": {
            "started": "2026-03-02T09:00:00",
            "operator": "lab",
            "tolerance_profile": "mpu6000",
            "settings": {"scale_1g": {a: truth[a][f"a_{a}"] for a in "xyz"}},
        },
        "site": {"latitude_deg": 50.0},
    }
    write_centrifuge_run(sim, folder, manifest)
    return folder


def _assert_nothing_cut(text: str, ids: set[str]) -> None:
    assert "…" not in text, text
    for token in RUN_ID.findall(text):
        assert token in ids, f"run id {token!r} cut or unknown in:\n{text}"
    for token in ABS_PATH.findall(text):
        assert Path(token).exists(), f"path {token!r} cut in:\n{text}"


def _commands(demo: dict) -> list[list[str]]:
    a = ["--archive", demo["archive"]]
    tmp = demo["tmp"]
    run = sorted(demo["ids"])[0]
    mpu = SAMPLES / "mpu6000_MPU0001"
    return [
        ["history", "IMU-R-0003", *a],
        ["show", run, *a],
        ["show", run[:6], *a],
        [
            "export",
            run,
            *a,
            "--format",
            "px4",
            "--device-id",
            "1310988",
            "-o",
            str(tmp / "u.params"),
        ],
        ["export", run, *a, "--format", "csv"],
        ["report", run, *a, "--no-pdf"],
        ["reprocess", run, "--reason", "width test", *a],
        ["inspect", str(SAMPLES / "csv_IMU-2026-0042")],
        ["procedures"],
        ["repeatability", "IMU-R-0003", *a],
        [
            "apply",
            str(mpu / "MPU0001_x_up.txt"),
            str(tmp / "applied.csv"),
            "--serial",
            "MPU0001",
            *a,
        ],
        ["trend", "IMU-R-0003", "acc.bias.z", *a],
        ["fleet", "MPU-6000", "acc.bias.z", *a],
        ["query", "latest", "IMU-R-0003", *a],
        ["query", "lineage", run, "acc.bias.x", *a],
        ["navfit", run, "--profile", "static-alignment", *a],
        ["validate", run, "--with", "allantools", *a],
        ["query", "lapsed", "CUBE-7", *a],
        ["impact", "DAQ-12", "--from", "2026-01-01", "--error", "clock_error_ppm=500", *a],
        ["query", "units", *a],
        ["query", "due", "--before", "2030-01-01", *a],
        ["due", *a],
        ["query", "history", "IMU-R-0003", "acc.bias.z", *a],
        ["query", "fleet", "MPU-6000", "acc.bias.z", *a],
        [
            "thermal",
            "export",
            "IMU-T-0007",
            str(tmp / "t.params"),
            "--format",
            "px4",
            "--device-id",
            "7",
            *a,
        ],
        ["thermal", "show", "IMU-T-0007", *a],
        ["centrifuge", "solve", str(demo["centrifuge"])],
        ["centrifuge", "plan", "--radius", "0.5"],
        ["keygen", str(tmp / "me.key"), "--name", "A. Tester"],
        ["approve", run, "--key", str(tmp / "me.key"), *a],
        ["audit", *a],
        ["verify", *a],
        [
            "verify-certificate",
            str(tmp / "unsigned.xml"),
            "--certificate",
            str(tmp / "lab-cert.pem"),
        ],
        ["checkpoint", "-o", str(tmp / "checkpoint.json"), *a],
        ["serve-user", str(tmp / "users"), "tester"],
        ["backup", str(tmp / "backup"), *a],
        ["restore", str(tmp / "backup"), "--archive", str(tmp / "restored")],
    ]


@pytest.mark.slow
def test_every_subcommand_keeps_run_ids_and_paths_whole(
    demo: dict, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CALIB_KEY_PASSPHRASE", "a passphrase for the width test")
    monkeypatch.setenv("CALIB_SERVE_PASSWORD", "a password for the width test")
    for text in demo["outputs"]:
        _assert_nothing_cut(text, demo["ids"])
    for args in _commands(demo):
        code, text = _invoke(*args)
        assert code in (0, 1), f"calib {' '.join(args)}: exit {code}\n{text}"
        _assert_nothing_cut(text, demo["ids"])
        assert "PosixPath(" not in text and "Archive(" not in text, text


def test_every_registered_command_is_driven(demo: dict) -> None:
    """The list above covers every subcommand calib has (serve, a server, aside)."""
    groups = {g.name for g in app.registered_groups}
    driven = {tuple(c[:2]) if c[0] in groups else (c[0],) for c in _commands(demo)}
    driven |= {("process",), ("thermal", "fit"), ("serve",)}
    known = {(i.name or i.callback.__name__,) for i in app.registered_commands}
    for group in app.registered_groups:
        known |= {(group.name, c.name) for c in group.typer_instance.registered_commands}
    assert known <= driven, known - driven


def test_fleet_and_trend_write_a_png_only_when_asked(
    demo: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    for args in (["fleet", "MPU-6000", "acc.bias.z"], ["trend", "IMU-R-0003", "acc.bias.z"]):
        code, text = _invoke(*args, "--archive", demo["archive"])
        assert code == 0, text
        assert list(tmp_path.iterdir()) == [], text
        code, text = _invoke(*args, "--archive", demo["archive"], "--plot", "p.png")
        assert code == 0 and (tmp_path / "p.png").stat().st_size > 1000, text
        (tmp_path / "p.png").unlink()


def test_wide_shows_every_column_and_narrow_names_the_hidden(demo: dict) -> None:
    code, narrow = _invoke("query", "units", "--archive", demo["archive"])
    assert code == 0 and "calib --wide shows every column" in narrow
    hidden = narrow.split("not shown at this width: ", 1)[1].split(";", 1)[0].split(", ")
    code, wide = _invoke("--wide", "query", "units", "--archive", demo["archive"])
    assert code == 0 and "not shown" not in wide
    header = next(line for line in wide.splitlines() if "serial" in line and "┃" in line)
    for name in hidden:
        assert name.replace("_", " ")[:6] in header, (name, header)
