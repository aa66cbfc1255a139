"""Support code for the tests, the benchmarks and the sample generator; not part of the product.

Not installed with the product (pyproject.toml installs calib_core, storage and pipelines
only); importable from a checkout, where `python -m pytest`, the benchmarks and
scripts/make_data_samples.py put the repository root on the path. No product module imports
it (tests/test_layers.py).

- archives: small archives of runs given at the parameter level (read-side tests);
- pgserver: a private, throw-away PostgreSQL server (fsync off) for tests and benchmarks;
- ros_messages: ROS message definitions and packed Imu layouts (MCAP / bag writers);
- run_writers: writers of run folders in the layouts ingest reads (data_samples/, tests);
- watchdog: stops a run's servers and removes its folders when the run ends, however.
"""
