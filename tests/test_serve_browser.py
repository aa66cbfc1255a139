"""`calib serve` in a real browser: Debian's chromium driven by Playwright.

The server is the real `calib serve` process on the sample archive (tests/serve_sample.py).
The test follows links as a person would (runs -> run -> a value's lineage -> its raw
file, the unit, the fleet, the equipment, verify), applies filters through the form,
checks that hostile archived strings and a hostile serial in the URL show as text (and
no dialog opens), reads a page with JavaScript disabled, and saves a screenshot of each
page into the test's output folder (also into $CALIB_SCREENSHOTS when set).

Chromium comes from Debian (scripts/ensure_system_packages.sh installs it); Playwright's
own browser download is not used.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pytest
from serve_sample import (
    DRIFT_SERIAL,
    EVIL_SERIAL,
    HOSTILE_MODEL,
    HOSTILE_OPERATOR,
    HOSTILE_SERIAL,
)
from test_serve import start_server

from storage import queries

pytestmark = pytest.mark.browser

CHROMIUM = Path("/usr/bin/chromium")


@pytest.fixture(scope="module")
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError as exc:  # the `test` extra installs it
        pytest.fail(f"playwright is not installed: {exc}")
    if not CHROMIUM.is_file():
        message = "Debian's chromium is missing (scripts/ensure_system_packages.sh installs it)"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=["--no-sandbox"])
        yield b
        b.close()


@pytest.fixture(scope="module")
def server(serve_sample):
    proc, base = start_server(serve_sample.archive.root)
    yield base
    proc.terminate()
    proc.wait(10)


@pytest.fixture
def shots(tmp_path: Path):
    """save(page, name): a full-page screenshot into tmp_path/screens (and $CALIB_SCREENSHOTS)."""
    folder = tmp_path / "screens"
    folder.mkdir()
    extra = os.environ.get("CALIB_SCREENSHOTS")

    def save(page, name: str) -> Path:  # noqa: ANN001 - a Playwright Page
        path = folder / f"{name}.png"
        page.screenshot(path=str(path), full_page=True)
        assert path.stat().st_size > 5_000, f"screenshot {name} is (almost) empty"
        if extra:
            Path(extra).mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, Path(extra) / path.name)
        return path

    return save


@pytest.fixture
def page(browser):
    context = browser.new_context(viewport={"width": 1280, "height": 900}, accept_downloads=True)
    pg = context.new_page()
    pg.dialogs = []  # an injected script's alert() would land here
    pg.on("dialog", lambda d: (pg.dialogs.append(d.message), d.dismiss()))
    yield pg
    assert pg.dialogs == [], f"a script ran on the page: {pg.dialogs}"
    context.close()


def test_follow_runs_to_run_to_lineage_to_raw_file(page, server, serve_sample, shots):
    page.goto(server + "/runs")
    total = sum(len(v) for v in serve_sample.runs.values())
    assert page.locator("#runs tr").count() == total + 1
    shots(page, "01-runs")

    page.fill("input[name=serial]", DRIFT_SERIAL)
    page.select_option("select[name=verdict]", "pass")
    page.click("#apply-filters")
    assert f"serial={DRIFT_SERIAL}" in page.url and "verdict=pass" in page.url
    df = queries.units(serve_sample.archive, verdict="pass")
    expected = sorted(df.loc[df["serial"] == DRIFT_SERIAL, "run_id"])
    shown = sorted(page.locator("#runs td.mono a").all_inner_texts())
    assert shown == expected and expected
    shots(page, "02-runs-filtered")

    page.click(f"#runs a:text-is('{expected[0]}')")
    assert page.url.endswith(f"/runs/{expected[0]}")
    assert expected[0] in page.inner_text("h1")
    assert page.locator("svg.chart").count() == 2  # residual plots of acc and gyro
    shots(page, "03-run")

    page.click("#parameters a >> nth=0")
    assert "/lineage/" in page.url
    summary = queries.run_summary(serve_sample.archive, expected[0])
    raw = summary.raw_files[0]
    assert raw.sha256 in page.inner_text("#raw-files")
    shots(page, "04-lineage")
    with page.expect_download() as info:
        page.click(f"#raw-files a:text-is('{raw.name}')")
    data = Path(info.value.path()).read_bytes()
    assert hashlib.sha256(data).hexdigest() == raw.sha256


def test_unit_fleet_equipment_and_verify_pages(page, server, serve_sample, shots):
    run_id = serve_sample.runs[DRIFT_SERIAL][0]
    page.goto(f"{server}/runs/{run_id}")
    page.click("#unit-link")
    assert page.url.endswith(f"/units/{DRIFT_SERIAL}")
    assert page.locator("#trend + svg.chart circle").count() == len(serve_sample.runs[DRIFT_SERIAL])
    shots(page, "05-unit-trend")
    page.click("#parameters a:text-is('gyr.noise.z')")
    assert "parameter=gyr.noise.z" in page.url
    assert page.locator("#trend + svg.chart text:text-is('gyr.noise.z of DRIFT-01')").count() == 1

    page.goto(f"{server}/units/TH-01")
    assert page.locator("svg.chart").count() == 5  # the trend and four thermal families
    shots(page, "06-unit-thermal")

    page.click("header a:text-is('Fleets')")
    page.click("#models a:text-is('MPU-6000')")
    page.select_option("select[name=parameter]", "gyr.noise.x")
    page.click("#show-parameter")
    assert "parameter=gyr.noise.x" in page.url
    assert page.locator("svg.chart rect.bar").count() >= 1
    shots(page, "07-fleet")

    page.click("header a:text-is('Equipment')")
    shots(page, "08-equipment")
    page.click("#equipment a:text-is('CUBE-D')")
    assert page.locator("#lapsed tr").count() == 1 + 2
    shots(page, "09-equipment-item")

    page.click("header a:text-is('Verify')")
    page.click("#run-verify")
    assert page.inner_text("#verify-result") == "OK"
    shots(page, "10-verify")


def test_hostile_strings_render_as_text(page, server, serve_sample, shots):
    page.goto(f"{server}/runs?serial={HOSTILE_SERIAL}")
    assert HOSTILE_SERIAL in page.inner_text("#error-message")
    shots(page, "11-hostile-serial")
    (run_id,) = serve_sample.runs[EVIL_SERIAL]
    page.goto(f"{server}/runs/{run_id}")
    text = page.inner_text("main")
    assert HOSTILE_MODEL in text and HOSTILE_OPERATOR in text
    assert page.locator("main script, main img").count() == 0
    shots(page, "12-hostile-run")


def test_pages_work_without_javascript(browser, server, serve_sample, shots):
    context = browser.new_context(
        java_script_enabled=False, viewport={"width": 1280, "height": 900}
    )
    pg = context.new_page()
    pg.goto(f"{server}/runs?per_page=10")
    pg.click("a[rel=next]")  # paging is plain links
    assert "page=2" in pg.url and pg.locator("#runs tr").count() > 1
    pg.select_option("select[name=model]", "MPU-6000")
    pg.click("#apply-filters")  # a plain GET form: no script needed
    assert "model=MPU-6000" in pg.url
    pg.click("#runs td.mono a >> nth=0")
    assert pg.locator("#parameters tr").count() > 1
    shots(pg, "13-run-no-javascript")
    context.close()


def test_navigation_pages(page, server, serve_sample, shots):
    run_id = serve_sample.runs[DRIFT_SERIAL][-1]
    page.goto(f"{server}/runs/{run_id}")
    page.click("#navigation-link")
    assert page.url.endswith(f"/runs/{run_id}/navigation")
    page.select_option("select[name=profile]", "multicopter-flight")
    page.click("#show-profile")  # a plain GET form
    assert "profile=multicopter-flight" in page.url
    assert page.locator("svg.chart").count() == 3
    assert page.locator("#figures tr").count() == 1 + 7
    shots(page, "14-run-navigation")
    page.goto(f"{server}/fleet?model=MPU-6000")
    page.click("#navigation-link")
    assert "/fleet/navigation?model=MPU-6000" in page.url
    df = queries.units(serve_sample.archive, model="MPU-6000", verdict="pass")
    assert page.locator("#fleet-navigation tr").count() == 1 + df["serial"].nunique()
    shots(page, "15-fleet-navigation")
