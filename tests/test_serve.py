"""`calib serve` over plain HTTP: every route on an archive built by the real pipeline.

The expected values come from the archive itself (storage.queries, the raw files' hashes
in the database, the simulator's drift), so a page that shows another number, drops a
row, or lets a string through unescaped fails.
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import socket
import subprocess
import sys
import time
from datetime import UTC, datetime
from html.parser import HTMLParser
from pathlib import Path

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient
from serve_sample import (
    DATA_SAMPLES,
    DRIFT_PER_DAY,
    DRIFT_SERIAL,
    EVIL_SERIAL,
    HOSTILE_EQUIPMENT,
    HOSTILE_MODEL,
    HOSTILE_OPERATOR,
    HOSTILE_SERIAL,
    THERMAL_SERIAL,
)
from sqlalchemy import text
from typer.testing import CliRunner

from pipelines.cli import app as cli
from pipelines.web.app import create_app
from storage import queries
from storage.db import ReadOnlyArchiveError, resolve_archive

HOSTILE = (HOSTILE_MODEL, HOSTILE_OPERATOR, HOSTILE_EQUIPMENT, HOSTILE_SERIAL, "<b>ACME</b>")


class Page(HTMLParser):
    """Tags, text and links of a page; fails the test on a <script> or an event attribute."""

    def __init__(self, html: str) -> None:
        super().__init__()
        self.links: list[str] = []
        self.text: list[str] = []
        self.tables: dict[str, int] = {}  # table id -> rows
        self._table: str | None = None
        self.feed(html)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        assert tag not in ("script", "iframe", "object", "embed", "img"), f"<{tag}> on the page"
        a = dict(attrs)
        assert not [k for k in a if k.startswith("on")], f"event attribute in <{tag} {attrs}>"
        if tag == "a" and a.get("href"):
            self.links.append(a["href"])
        if tag == "table":
            self._table = a.get("id")
            self.tables[self._table or ""] = 0
        if tag == "tr" and self._table is not None:
            self.tables[self._table] += 1

    def handle_data(self, data: str) -> None:
        self.text.append(data)

    @property
    def body(self) -> str:
        return " ".join(" ".join(self.text).split())


def get(client: TestClient, url: str, status: int = 200) -> Page:
    r = client.get(url)
    assert r.status_code == status, (url, r.status_code, r.text[-500:])
    assert r.headers["content-type"].startswith("text/html")
    assert "script-src" not in r.headers["content-security-policy"]  # default-src 'none'
    return Page(r.text)


def rows(page: Page, table: str) -> int:
    return page.tables[table] - 1  # the header row


def test_runs_list_filters_sort_and_pages(client, serve_sample):
    runs = serve_sample.runs
    total = sum(len(v) for v in runs.values())
    assert rows(get(client, "/runs"), "runs") == total
    page = get(client, f"/runs?serial={DRIFT_SERIAL}")
    assert rows(page, "runs") == len(runs[DRIFT_SERIAL])
    assert {f"/runs/{r}" for r in runs[DRIFT_SERIAL]} <= set(page.links)
    # Lab temperature -10..5 deg C: the two coldest campaign points.
    assert rows(get(client, "/runs?temp_min=-10&temp_max=5"), "runs") == 2
    # Runs of a date range: the drift unit's runs of 2025 (days 0, 120, 300).
    assert rows(get(client, "/runs?from=2025-01-01&to=2025-12-31"), "runs") == 3
    df = queries.units(serve_sample.archive, verdict="fail")
    assert rows(get(client, "/runs?verdict=fail"), "runs") == len(df) > 0
    assert (
        rows(get(client, "/runs?model=MPU-6000&procedure=six_position_integral"), "runs")
        == total - 1
    )
    # Sorted by serial, ascending: the serials in the order the database sorts them.
    page = get(client, "/runs?sort=serial&order=asc&per_page=200")
    serials = [s for s in sorted(runs) for _ in runs[s]]
    shown = [h.split("/")[-1] for h in page.links if h.startswith("/units/")]
    assert shown == serials
    # Paged by 10: the second page holds the rest, and links back.
    second = get(client, "/runs?per_page=10&page=2")
    assert rows(second, "runs") == total - 10
    assert any("page=1" in h for h in second.links)
    assert "page 2 of 2" in second.body


@pytest.mark.parametrize(
    "url, status, says",
    [
        ("/runs?colour=red", 400, "unknown query parameter 'colour'"),
        ("/runs?page=0", 400, "page: expected a whole number"),
        ("/runs?per_page=7", 400, "per_page: expected one of"),
        ("/runs?sort=password", 400, "sort: expected one of"),
        ("/runs?from=2024-13-01", 400, "from: expected a date YYYY-MM-DD"),
        ("/runs?from=2025-02-01&to=2025-01-01", 400, "date range"),
        ("/runs?verdict=maybe", 400, "verdict: expected one of pass, fail, needs review"),
        ("/runs?temp_min=warm", 400, "temp_min: expected a number"),
        ("/runs?serial=a&serial=b", 400, "given more than once"),
        ("/runs/R000000000000", 404, "no run 'R000000000000'"),
        ("/runs/.hidden", 400, "invalid run id"),
        ("/units/NOPE-1", 404, "no unit with serial 'NOPE-1'"),
        ("/fleet", 400, "model: expected 1-200 printable characters"),
        ("/fleet?model=NoSuchModel", 404, "no units of model 'NoSuchModel'"),
        ("/fleet?model=MPU-6000&parameter=acc.bias.w", 400, "not a canonical parameter name"),
        ("/equipment/item?kind=cube&serial=NOPE", 404, "no equipment cube 'NOPE'"),
        ("/verify?run=yes", 400, "run: expected one of 0, 1"),
    ],
)
def test_bad_requests_get_a_clear_4xx(client, url, status, says):
    page = get(client, url, status)
    assert says in page.body


def test_hostile_serial_in_a_request_is_shown_as_text(client):
    r = client.get("/runs", params={"serial": HOSTILE_SERIAL})
    assert r.status_code == 400
    assert HOSTILE_SERIAL not in r.text
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in r.text
    assert HOSTILE_SERIAL in Page(r.text).body  # the text, as text
    r = client.get("/units/" + HOSTILE_SERIAL.replace("/", "%2F"))
    assert r.status_code in (400, 404) and HOSTILE_SERIAL not in r.text


def test_hostile_archived_strings_are_escaped_everywhere(client, serve_sample):
    (run_id,) = serve_sample.runs[EVIL_SERIAL]
    urls = [
        f"/runs/{run_id}",
        "/runs",
        f"/units/{EVIL_SERIAL}",
        "/models",
        "/equipment",
        f"/runs/{run_id}/lineage/acc.bias.x",
    ]
    urls.append("/fleet?" + httpx.QueryParams(model=HOSTILE_MODEL).__str__())
    urls.append("/equipment/item?" + str(httpx.QueryParams(kind="daq", serial=HOSTILE_EQUIPMENT)))
    for url in urls:
        r = client.get(url)
        assert r.status_code == 200, (url, r.text[-300:])
        for s in HOSTILE:
            assert s not in r.text, (url, s)
        page = Page(r.text)  # no <script>, <img>, no on* attribute
        assert HOSTILE_MODEL in page.body or HOSTILE_EQUIPMENT in page.body, url
    assert HOSTILE_OPERATOR in get(client, f"/runs/{run_id}").body


def test_run_page_shows_the_archived_run(client, serve_sample):
    run_id = serve_sample.runs[DRIFT_SERIAL][0]
    s = queries.run_summary(serve_sample.archive, run_id)
    page = get(client, f"/runs/{run_id}")
    assert rows(page, "parameters") == len(s.calibration.parameters)
    assert rows(page, "checks") == len(s.calibration.checks)
    assert rows(page, "steps") == len(s.calibration.steps)
    assert rows(page, "raw-files") == len(s.raw_files)
    for f in s.raw_files:
        assert f.sha256 in page.body
    # Every parameter value links to its lineage; the cube lapsed after this run's day.
    for p in s.calibration.parameters:
        assert f"/runs/{run_id}/lineage/{p.name}" in page.links
    assert "CUBE-D" in page.body and "valid" in page.body
    assert "<= 0.05" in page.body  # gyro noise: an upper limit (deg/s), not +-
    last = get(client, f"/runs/{serve_sample.runs[DRIFT_SERIAL][-1]}")
    assert "lapsed" in last.body
    assert re.search(r"Accelerometer residuals per segment", client.get(f"/runs/{run_id}").text)


def test_run_page_marks_model_checks_for_review(client, serve_sample):
    """Identifiability (model:), repeatability and device checks come through the run's
    checks list; failed, they are badged "needs review" as the run's verdict counts them,
    any other failed check "fail"."""
    from calib_core.calibration import CheckResult
    from pipelines.web.present import check_result

    assert check_result(CheckResult("model:acc_dof", None, None, False)) == "needs review"
    assert check_result(CheckResult("model:face_bias.x", None, None, True)) == "pass"
    assert check_result(CheckResult("gyr.noise.x", None, None, False)) == "fail"
    run_id = serve_sample.runs[DRIFT_SERIAL][0]
    checks = queries.run_summary(serve_sample.archive, run_id).calibration.checks
    html = client.get(f"/runs/{run_id}").text
    model = [c for c in checks if c.name.startswith("model:")]
    assert model, "the pipeline archives its model checks with the run"
    for c in model:
        badge = "needs review" if not c.passed else "pass"
        assert re.search(
            rf'{re.escape(c.name)}</td>.*?<span class="badge '
            rf'{badge.replace(" ", "-")}">{badge}</span>',
            html,
            re.S,
        ), c["name"]


def test_lineage_page_traces_the_value_to_raw_bytes(client, serve_sample):
    run_id = serve_sample.runs[DRIFT_SERIAL][0]
    lin = queries.lineage(serve_sample.archive, run_id, "gyr.scale.x")
    page = get(client, f"/runs/{run_id}/lineage/gyr.scale.x")
    for f in lin["raw_files"]:
        assert f["sha256"] in page.body
        assert f"/runs/{run_id}/raw/{f['name']}" in page.links
    assert lin["calibration"]["settings_hash"] in page.body
    assert lin["calibration"]["software_version"] in page.body
    assert f"{lin['parameter']['values'][0]['value']:.10g}" in page.body
    get(client, f"/runs/{run_id}/lineage/acc.k2.x", 404)  # valid name, not in this run
    get(client, f"/runs/{run_id}/lineage/gyr.scale.x?revision=2", 404)


@pytest.mark.slow
def test_downloads_are_the_archived_bytes_and_documents(client, serve_sample):
    run_id = serve_sample.runs[DRIFT_SERIAL][0]
    s = queries.run_summary(serve_sample.archive, run_id)
    for f in s.raw_files:
        r = client.get(f"/runs/{run_id}/raw/{f.name}")
        assert r.status_code == 200
        assert hashlib.sha256(r.content).hexdigest() == f.sha256
    assert client.get(f"/runs/{run_id}/raw/..%2F..%2Farchive.sqlite").status_code == 404
    r = client.get(f"/runs/{run_id}/export.json")
    assert json.loads(r.content) == json.loads(
        json.dumps(queries.export_calibration(serve_sample.archive, run_id), default=str)
    )
    assert "attachment" in r.headers["content-disposition"]
    r = client.get(f"/runs/{run_id}/protocol.txt")
    assert r.status_code == 200 and DRIFT_SERIAL in r.text
    # The suite archives without typesetting (conftest); this run's certificate is issued
    # as `calib report` would, then handed out by the read-only pages.
    from pipelines.reports.issue import issue, issued

    if issued(serve_sample.archive, run_id) is None:
        issue(serve_sample.archive, run_id)
    r = client.get(f"/runs/{run_id}/certificate.html")
    assert r.status_code == 200 and DRIFT_SERIAL in r.text and run_id in r.text
    r = client.get(f"/runs/{run_id}/certificate.pdf")
    assert r.status_code == 200 and r.content.startswith(b"%PDF")


def test_export_downloads_are_the_calib_export_files(client, serve_sample, tmp_path):
    from scipy.io import loadmat

    from pipelines.run_export import export_run

    run_id = serve_sample.runs[THERMAL_SERIAL][2]  # a unit with a thermal model
    links = get(client, f"/runs/{run_id}").links
    # its CSV runs record no PX4 device id: refused naming it, given it is the CLI's file
    r = client.get(f"/runs/{run_id}/export.px4")
    assert r.status_code == 400 and "--device-id" in r.text
    for fmt in ("px4", "ardupilot", "csv", "mat"):
        url = f"/runs/{run_id}/export.{fmt}"
        assert url in links
        r = client.get(url + ("?device_id=1310988" if fmt == "px4" else ""))
        assert r.status_code == 200, (url, r.text[-300:])
        assert "attachment" in r.headers["content-disposition"]
        ids = {"accel_id": 1310988, "gyro_id": 1310988} if fmt == "px4" else {}
        want = export_run(serve_sample.archive, run_id, fmt, **ids)
        assert want.filename in r.headers["content-disposition"]
        if fmt != "mat":  # text: the same bytes as `calib export`
            assert r.content == want.data
            continue
        (tmp_path / "a.mat").write_bytes(r.content)  # savemat stamps its creation time
        (tmp_path / "b.mat").write_bytes(want.data)
        got, ref = loadmat(tmp_path / "a.mat"), loadmat(tmp_path / "b.mat")
        assert got.keys() == ref.keys()
        np.testing.assert_array_equal(got["thermal_coef"], ref["thermal_coef"])
        np.testing.assert_array_equal(got["parameter_values"], ref["parameter_values"])
    assert b"TC_A0_X0_0" in client.get(f"/runs/{run_id}/export.px4?device_id=7").content
    assert client.get(f"/runs/{run_id}/export.xls").status_code == 404
    assert client.get(f"/runs/{run_id}/export.px4?revision=7").status_code == 404
    assert client.get(f"/runs/{run_id}/export.px4?instance=1").status_code == 400
    assert client.get("/runs/Rnothere0000/export.csv").status_code == 404


def test_run_page_asks_for_the_px4_device_id_its_log_does_not_record(client, serve_sample):
    """The run page's PX4 form (a plain GET form, no script) sends the device id the
    download needs when the run's log records none; the file then names it."""
    run_id = serve_sample.runs[THERMAL_SERIAL][2]
    html = client.get(f"/runs/{run_id}").text
    form = re.search(
        r'<form[^>]*id="px4-export"[^>]*action="([^"]+)"[^>]*>(.*?)</form>', html, re.S
    )
    assert form is not None and form.group(1) == f"/runs/{run_id}/export.px4"
    assert re.search(r'<input name="device_id"[^>]*required', form.group(2))
    r = client.get(form.group(1), params={"device_id": "1310988"})
    assert r.status_code == 200
    # QGroundControl's lines: vehicle, component, name, value, type
    ids = re.findall(r"^\S+\s+\S+\s+TC_[AG]0_ID\s+(\d+)", r.text, re.M)
    assert ids == ["1310988", "1310988"], r.text[:800]


def test_unit_page_drift_is_rounded_as_calib_trend_rounds_it(client, serve_sample):
    """The drift per year on the unit page and in `calib trend`: one rounding (the u to two
    significant digits, the slope to its place) of the same fit."""
    from pipelines.reports.display import shown
    from pipelines.trends import trend_report

    page = get(client, f"/units/{DRIFT_SERIAL}?parameter=acc.bias.x")
    row = re.search(r"acc\.bias\.x 4 \S+ \S+ m/s\^2 (\S+) ± (\S+)", page.body)
    summary = trend_report(serve_sample.archive, DRIFT_SERIAL, "acc.bias.x")["summary"]
    s = shown("acc.bias.x", summary["slope_per_year"], summary["slope_std_per_year"])
    assert row and (row[1], row[2]) == (s.value, s.u), (row and row.group(), s)
    assert len(s.u.lstrip("0.")) == 2  # two significant digits


def test_unit_page_trend_recovers_the_simulated_drift(client, serve_sample):
    page = get(client, f"/units/{DRIFT_SERIAL}?parameter=acc.bias.x")
    # Drift per year of acc.bias.x (m/s^2, its display unit) with its standard uncertainty.
    row = re.search(r"acc\.bias\.x 4 \S+ \S+ m/s\^2 (\S+) ± (\S+)", page.body)
    assert row, page.body[:2000]
    slope, u = float(row[1]), float(row[2])
    assert abs(slope - DRIFT_PER_DAY * 365.25) < 3 * u, (slope, u)
    assert rows(page, "history") == len(serve_sample.runs[DRIFT_SERIAL])
    for run_id in serve_sample.runs[DRIFT_SERIAL]:  # each point of the chart links to lineage
        assert f"/runs/{run_id}/lineage/acc.bias.x" in page.links
    get(client, f"/units/{DRIFT_SERIAL}?parameter=acc.k2.x", 404)
    get(client, f"/units/{DRIFT_SERIAL}?parameter=nonsense", 400)


def test_unit_page_draws_the_thermal_model(client):
    r = client.get(f"/units/{THERMAL_SERIAL}")
    assert r.status_code == 200
    for family in ("acc.bias", "gyr.bias", "acc.scale", "gyr.scale"):
        assert f"{family} against temperature" in r.text


def test_fleet_equipment_models_and_verify_pages(client, serve_sample):
    page = get(client, "/models")
    assert "/fleet?model=MPU-6000" in page.links
    page = get(client, "/fleet?model=MPU-6000&parameter=gyr.noise.x")
    valid = queries.fleet(serve_sample.archive, "MPU-6000", "gyr.noise.x")["serial"].nunique()
    assert f"{valid} unit(s) have one" in page.body
    # IMU-2026-0042 fails on gyro noise: its latest run did not pass.
    assert "IMU-2026-0042" in [h.split("/")[-1] for h in page.links if h.startswith("/units/")]
    page = get(client, "/equipment")
    assert "/equipment/item?kind=cube&serial=CUBE-D" in page.links
    page = get(client, "/equipment/item?kind=cube&serial=CUBE-D")
    lapsed = queries.lapsed_runs(serve_sample.archive, "CUBE-D", "cube")
    assert rows(page, "lapsed") == len(lapsed) == 2
    assert "cube CUBE-D lapsed" in page.body  # due 2025-06-30: lapsed today
    page = get(client, "/verify")
    assert "/verify?run=1" in page.links
    assert "OK" in get(client, "/verify?run=1").body


def test_verify_page_reports_a_changed_raw_file(serve_sample, tmp_path):
    copy = tmp_path / "archive"
    shutil.copytree(serve_sample.archive.root, copy)
    obj = next(p for p in (copy / "objects").rglob("*") if p.is_file())
    obj.write_bytes(obj.read_bytes() + b"tampered")
    ro = queries.open_readonly(resolve_archive(str(copy)))
    with TestClient(create_app(ro)) as c:
        page = get(c, "/verify?run=1")
    ro.dispose()
    assert "1 problem(s)" in page.body and "mismatch" in page.body


def test_the_server_cannot_write(client, serve_sample):
    db = Path(serve_sample.archive.url.removeprefix("sqlite:///"))
    before = hashlib.sha256(db.read_bytes()).hexdigest()
    for method in ("post", "put", "delete", "patch"):
        r = client.request(method.upper(), "/runs")
        assert r.status_code == 405
    ro = client.app.state.archive
    with pytest.raises(Exception, match="readonly|read-only|read only"), ro.engine().begin() as c:
        c.execute(text("DELETE FROM runs"))
    with pytest.raises(ReadOnlyArchiveError):  # never migrated (upgrade only checks the head)
        ro.migrate("head")
    assert hashlib.sha256(db.read_bytes()).hexdigest() == before


def test_open_readonly_is_the_archive_read_only(serve_sample):
    """One read-only opener: the server's is storage.db.Archive(read_only=True)."""
    from sqlalchemy.exc import OperationalError

    from storage.db import Archive

    ro = queries.open_readonly(serve_sample.archive)
    assert type(ro) is Archive and ro.read_only
    with ro.engine().connect() as conn:
        assert conn.exec_driver_sql("PRAGMA query_only").scalar_one() == 1
    with pytest.raises(OperationalError, match="readonly"), ro.engine().begin() as conn:
        conn.exec_driver_sql("DELETE FROM check_results")
    with pytest.raises(ReadOnlyArchiveError, match="read-only"):
        ro.migrate("head")
    ro.upgrade()  # at head: only checked, as for every read-only archive
    ro.dispose()


def test_open_readonly_never_creates_an_archive(tmp_path):
    with pytest.raises(FileNotFoundError, match="no archive database"):
        queries.open_readonly(resolve_archive(str(tmp_path / "none")))
    assert not (tmp_path / "none").exists()
    result = CliRunner().invoke(cli, ["serve", "--archive", str(tmp_path / "none")])
    assert result.exit_code == 2 and "no archive database" in result.output


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(archive_root: Path) -> tuple[subprocess.Popen, str]:
    """`calib serve` as a real process on a free port; returns it and its base URL."""
    port = _free_port()
    code = "from pipelines.cli import app; app()"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "serve", "--archive", str(archive_root), "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if httpx.get(base + "/runs", timeout=2).status_code == 200:
                return proc, base
        except httpx.HTTPError:
            pass
        if proc.poll() is not None:
            break
        time.sleep(0.2)
    proc.kill()
    raise RuntimeError(f"calib serve did not start: {proc.stdout.read().decode()[-2000:]}")


@pytest.mark.e2e
def test_calib_serve_command_serves_the_archive(serve_sample):
    proc, base = start_server(serve_sample.archive.root)
    try:
        r = httpx.get(base + "/", follow_redirects=True)
        assert r.status_code == 200 and str(r.url).endswith("/runs")
        assert DRIFT_SERIAL in r.text
    finally:
        proc.terminate()
        proc.wait(10)


@pytest.mark.postgres
def test_postgresql_is_browsed_as_the_read_only_role(postgres_url, tmp_path):
    """Owner URL: the server acts as calib_reader in read-only transactions; a writer that
    cannot become the reader is refused at the start."""
    from sqlalchemy.engine import make_url

    from pipelines.ingest import discover_runs
    from pipelines.process import process_run
    from storage.db import Archive
    from storage.roles import READER, WRITER, apply_roles

    owner = Archive(postgres_url, tmp_path / "store")
    owner.upgrade()
    run_ids = [process_run(s, owner)["run_id"] for s in discover_runs([DATA_SAMPLES])]
    apply_roles(owner)
    owner.dispose()
    ro = queries.open_readonly(owner)
    with ro.engine().connect() as conn:
        assert conn.execute(text("SELECT current_user")).scalar_one() == READER
    assert_fleet_pages_agree(ro, "MPU-6000")  # PostgreSQL's LATERAL picks
    with TestClient(create_app(ro)) as c:
        for url in [
            "/runs",
            f"/runs/{run_ids[0]}",
            f"/runs/{run_ids[0]}/lineage/acc.bias.x",
            "/units/MPU0001",
            "/fleet?model=MPU-6000",
            "/equipment",
            "/models",
            "/verify",
            f"/runs/{run_ids[0]}/export.json",
            f"/runs/{run_ids[0]}/export.px4?device_id=1310988",  # MPU-6000 files record none
            f"/runs/{run_ids[0]}/export.mat",
        ]:
            assert c.get(url).status_code == 200, url
        assert rows(get(c, "/runs?serial=MPU0001"), "runs") == 1
    with (
        pytest.raises(Exception, match="read-only transaction|permission denied"),
        ro.engine().begin() as conn,
    ):
        conn.execute(text("DELETE FROM check_results"))
    ro.dispose()
    as_writer = make_url(postgres_url).set(username=WRITER).render_as_string(hide_password=False)
    with pytest.raises(PermissionError, match=READER):
        queries.open_readonly(Archive(as_writer, tmp_path / "store"))
    as_reader = make_url(postgres_url).set(username=READER).render_as_string(hide_password=False)
    direct = queries.open_readonly(Archive(as_reader, tmp_path / "store"))
    with TestClient(create_app(direct)) as c:
        assert c.get("/runs").status_code == 200
    direct.dispose()


def assert_fleet_pages_agree(archive, model: str) -> None:  # noqa: ANN001 - an Archive
    """The fleet page's grouped and per-unit picks (storage.queries.fleets) answer as the
    archive's own queries: storage.queries.units with each unit's latest run by the rule of
    docs/archive.md (the run that started last; of equal starts the later archived, the
    larger ``runs.id``, whatever the order of their run ids) and storage.queries.fleet
    (values nearest 20 deg C)."""
    from calib_core import params

    with archive.engine().connect() as conn:
        archived = dict(conn.execute(text("SELECT run_id, id FROM runs")).all())
    runs = queries.units(archive, model=model)
    runs = runs.assign(archived=runs["run_id"].map(archived)).sort_values(
        ["started_at", "archived"]
    )
    latest = runs.groupby("serial").tail(1)
    fleet = queries.fleet_units(archive, model, failing_max=2)
    want = latest["verdict"].value_counts().to_dict()
    assert fleet.units == len(latest) > 0 and fleet.latest == want
    failing = sorted(latest.loc[latest["verdict"] != "pass", "serial"])
    assert [u["serial"] for u in fleet.failing] == failing[:2]
    assert fleet.n_failing == len(failing)
    for u in fleet.failing:
        assert u["runs"] == (runs["serial"] == u["serial"]).sum()
        assert u["run_id"] == latest.loc[latest["serial"] == u["serial"], "run_id"].item()
    for name in params.ACC_LINEAR + params.GYR_LINEAR:
        mine = queries.fleet_values(archive, model, name)
        queries.fleet_lineage(archive, mine)
        theirs = queries.fleet(archive, model, name)
        dist = (theirs["temperature_c"].fillna(20.0) - 20.0).abs()
        one = (
            theirs.assign(d=dist)
            .sort_values(["serial", "d", "temperature_c"])
            .groupby("serial")
            .head(1)
        )
        assert [(r["serial"], r["run_id"], r["value"]) for r in mine] == list(
            zip(one["serial"], one["run_id"], one["value"], strict=True)
        ), name


def test_browse_fleet_equals_the_archive_queries(serve_sample):
    assert_fleet_pages_agree(serve_sample.archive, "MPU-6000")


def test_the_fleet_oracle_takes_the_later_archived_of_equal_starts(archive, tmp_path):
    """Two runs of one unit started at one instant, the later archived failing with the
    run id that sorts first: the unit's latest run is the failing one, by the rule, and
    the oracle says so (a tie broken by run id text would take the passing one)."""
    from dataclasses import replace

    from test_queries import _run

    from storage.archive import archive_run
    from storage.run_input import raw_hash_of, run_id_of

    t = datetime(2025, 1, 2, 8, 0, tzinfo=UTC)
    pair = [_run(tmp_path, f"t{k}", "T1", 40 + k, t) for k in range(2)]
    pair.sort(key=lambda r: run_id_of(raw_hash_of([f.sha256 for f in r.raw_files])))
    first, second = pair[1], replace(pair[0], verdict="fail")  # later: its run id sorts first
    ids = [archive_run(archive, r).run_id for r in (first, second)]
    assert ids[1] < ids[0]
    fleet = queries.fleet_units(archive, first.device_model, failing_max=2)
    assert fleet.latest == {"fail": 1} and [u["run_id"] for u in fleet.failing] == [ids[1]]
    assert_fleet_pages_agree(archive, first.device_model)
