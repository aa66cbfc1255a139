"""`calib serve`'s navigation pages (docs/navigation.md, docs/serve.md): a run's calibration
over a mission profile and a model's units compared, on the sample archive
(tests/serve_sample.py: a unit with a thermal model, a unit with a drift line)."""

from __future__ import annotations

import pytest
from serve_sample import DRIFT_SERIAL, THERMAL_SERIAL
from test_serve import get, rows

from storage import queries


def test_run_page_links_to_its_navigation_performance(client, serve_sample):
    run_id = serve_sample.runs[THERMAL_SERIAL][-1]
    assert f"/runs/{run_id}/navigation" in get(client, f"/runs/{run_id}").links
    url = f"/runs/{run_id}/navigation?profile=land-vehicle-outage-60s"
    page = get(client, url)
    assert rows(page, "figures") == 7 and rows(page, "budget") == 7
    assert client.get(url).text.count("<svg") == 3  # attitude, velocity, position vs time
    assert "thermal gyr.bias" in " ".join(page.text)  # the thermal model's residual: a source


def test_drift_line_enters_as_a_source(client, serve_sample):
    run_id = serve_sample.runs[DRIFT_SERIAL][-1]  # the unit's latest: its interval applies
    page = get(client, f"/runs/{run_id}/navigation?profile=static-alignment")
    assert "drift acc.bias" in " ".join(page.text)


def test_fleet_navigation_compares_the_units(client, serve_sample):
    page = get(client, "/fleet/navigation?model=MPU-6000&profile=land-vehicle")
    df = queries.units(serve_sample.archive, model="MPU-6000", verdict="pass")
    assert rows(page, "fleet-navigation") == df["serial"].nunique() > 1
    assert "/fleet/navigation?model=MPU-6000" in get(client, "/fleet?model=MPU-6000").links


@pytest.mark.parametrize(
    "url",
    [
        "/runs/{run}/navigation?profile=../../etc/passwd",
        "/runs/{run}/navigation?profile=/tmp/x.toml",
        "/runs/{run}/navigation?planet=mars",
        "/fleet/navigation?profile=land-vehicle",
    ],
)
def test_bad_requests_are_refused(client, serve_sample, url):
    run_id = serve_sample.runs[DRIFT_SERIAL][0]
    get(client, url.format(run=run_id), 400)


def test_unknown_run_and_model_are_not_found(client):
    get(client, "/runs/R0000000000000/navigation", 404)
    get(client, "/fleet/navigation?model=NO-SUCH-MODEL", 404)
