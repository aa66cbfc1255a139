#!/usr/bin/env bash
# `make demo`: the whole product on data_samples/, each step said with how long it took.
# BIN: the environment's bin folder (default .venv/bin); DEMO_OUT: where the exports go.
set -euo pipefail
BIN=${BIN:-.venv/bin}
DEMO_OUT=${DEMO_OUT:-demo-output}
started=$SECONDS
step() {  # step N/TOTAL "what" command...
    local n=$1 what=$2 t0=$SECONDS
    shift 2
    echo "== $n $what =="
    "$@"
    echo "   ($(( SECONDS - t0 )) s)"
}
step 1/5 "processing every run of data_samples/ into ./calib-archive (certificates issued)" \
    "$BIN/calib" process data_samples --reports
step 2/5 "fitting the thermal model of the campaign IMU-T-0007" "$BIN/calib" thermal fit IMU-T-0007
mkdir -p "$DEMO_OUT"
export_both() {
    echo "   (PX4 needs the sensor's device id: the CSV samples record none, 1310988 stands for the vehicle's CAL_ACC0_ID)"
    "$BIN/calib" thermal export IMU-T-0007 "$DEMO_OUT/IMU-T-0007_px4.params" --format px4 \
        --device-id 1310988
    "$BIN/calib" thermal export IMU-T-0007 "$DEMO_OUT/IMU-T-0007_ardupilot.parm" --format ardupilot
}
step 3/5 "exporting it for PX4 and ArduPilot into $DEMO_OUT/" export_both
step 4/5 "the trend of IMU-R-0003's acc.bias.z (plot into $DEMO_OUT/)" \
    "$BIN/calib" trend IMU-R-0003 acc.bias.z --plot "$DEMO_OUT/IMU-R-0003_acc.bias.z_trend.png"
repeatability() {
    "$BIN/calib" repeatability IMU-R-0003 \
        || echo "(calib repeatability exits 1 here: the drift the sample was made with)"
}
step 5/5 "the repeatability of IMU-R-0003 (its acc.bias.z drifts on purpose: it fails)" repeatability
echo
echo "The demo took $(( SECONDS - started )) s (the installation before it not counted)."
echo "Open: calib-archive/runs/<serial>/<date>/<run>/ (protocols, HTML and PDF certificates);"
echo "      $DEMO_OUT/ (PX4 and ArduPilot parameter files, the trend plot)."
echo "Try:  $BIN/calib history IMU-R-0003"
echo "      $BIN/calib show <run id from the table above, or its first 4+ characters>"
echo "      $BIN/calib query latest MPU0001"
echo "      $BIN/calib thermal show IMU-T-0007"
echo "      $BIN/calib export <run id> --format ardupilot"
echo "      $BIN/calib serve        (browse the archive at http://127.0.0.1:8000/)"
echo "      $BIN/calib --help       (every command, grouped by task)"
