"""`calib serve`: a read-only web browser of the archive (docs/serve.md).

- app        the FastAPI application, templates, error pages
- auth       the login beyond loopback: users file (scrypt) or a reverse proxy's header
- forms      query-parameter validation (clear 400s naming the parameter)
- present    numbers and units for display (lab units, lineage links)
- runs       runs list, one run, lineage, raw files, downloads
- units      a unit's parameter history, trends, forecasts and thermal curves; model fleets
- equipment  equipment due dates and runs made while lapsed; the archive's verify status
- svg        server-side SVG charts
"""
