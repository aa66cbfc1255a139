"""Regenerate docs/screenshots/ from the sample archive: `make demo`'s archive of
data_samples/ (processed afresh into a temporary folder, the thermal campaign fitted)
served by the real `calib serve`, photographed with Playwright in Debian's chromium
(1200 x 900 viewport, full page).

    python scripts/screenshots.py [--out docs/screenshots]

Needs the test extra (playwright) and /usr/bin/chromium
(scripts/ensure_system_packages.sh). Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = Path("/usr/bin/chromium")
PORT = 8765


def pages(archive: Path) -> dict[str, str]:
    """Screenshot name -> page path of the sample archive."""
    sys.path.insert(0, str(ROOT))
    from storage import queries
    from storage.db import resolve_archive

    arch = resolve_archive(str(archive))
    run = queries.history_rows(arch, "MPU0001")[-1]["run_id"]
    return {
        "serve_runs": "/runs",
        "serve_run": f"/runs/{run}",
        "serve_unit_trend": "/units/IMU-R-0003?parameter=acc.bias.z",
        "serve_unit_thermal": "/units/IMU-T-0007?parameter=acc.bias.x",
        "serve_fleet": "/fleet?model=MPU-6000",
        "serve_equipment": "/equipment",
        "serve_equipment_item": "/equipment/item?kind=cube&serial=CUBE-7",
        "serve_verify": "/verify",
    }


def calib(*args: str, env: dict[str, str]) -> None:
    print("calib", *args, file=sys.stderr, flush=True)
    code = "from pipelines.cli import app; app()"
    subprocess.run(
        [sys.executable, "-c", code, *args], env=env, check=True, stdout=subprocess.DEVNULL
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "screenshots")
    out = parser.parse_args().out
    env = {
        **os.environ,
        "PYTHONPATH": str(ROOT),
        "DO_NOT_TRACK": "1",
        "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
        "CALIB_USER": "demo",
    }
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory(prefix="calib-screens-") as tmp:
        archive = Path(tmp) / "calib-archive"
        calib(
            "process",
            str(ROOT / "data_samples"),
            "--archive",
            str(archive),
            "--no-progress",
            env=env,
        )
        calib("thermal", "fit", "IMU-T-0007", "--archive", str(archive), env=env)
        server = subprocess.Popen(
            [
                sys.executable,
                "-c",
                "from pipelines.cli import app; app()",
                "serve",
                "--archive",
                str(archive),
                "--port",
                str(PORT),
            ],
            env=env,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            line = server.stderr.readline()  # "serving ..." once it accepts connections
            if not line.startswith("serving"):
                raise RuntimeError(f"calib serve did not start: {line}")
            base = f"http://127.0.0.1:{PORT}"
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=str(CHROMIUM), args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1200, "height": 900})
                out.mkdir(parents=True, exist_ok=True)
                for name, path in pages(archive).items():
                    with urllib.request.urlopen(base + path, timeout=120) as r:
                        assert r.status == 200, (path, r.status)
                    page.goto(base + path, wait_until="load", timeout=120_000)
                    time.sleep(0.2)
                    page.screenshot(path=str(out / f"{name}.png"), full_page=True)
                    print(f"wrote {out / f'{name}.png'} ({path})", file=sys.stderr)
                browser.close()
        finally:
            server.terminate()
            server.wait(timeout=60)


if __name__ == "__main__":
    main()
