"""The verdicts and the families of check names, alone (no numerics), so that the views
that only sort checks (`calib show`, the web's start) load none of the science stack."""

PASS, FAIL, NEEDS_REVIEW = "pass", "fail", "needs review"
REPEAT_PREFIX = "repeat:"
DEVICE_PREFIX = "device:"  # the unit's description against the archive's (pipelines.process)
# What the run could not determine or where its model misfits (the solvers' info
# "solver_checks"): the numbers may be right, a person must look before signing.
MODEL_PREFIX = "model:"
# Samples a preprocessing step replaced, counted against its false alarms
# (calib_core.preprocess.replaced).
REPLACED_PREFIX = f"{MODEL_PREFIX}replaced:"
# Findings about the record, not the unit (a log read to its last whole record, a turn
# that does not end quite at rest, a static record that moved, a detector's threshold
# raised): the run needs review with the finding named, never "fail" for it.
RECORD_PREFIX = "record:"
