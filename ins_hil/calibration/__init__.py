"""Calibration files and logs (the I/O around the pure fitting in :mod:`ins_hil.nav.calibration`).

* :mod:`ins_hil.calibration.files`: read and write the calibration file the gateway loads (TOML/JSON);
* :mod:`ins_hil.calibration.logs`: read a recorded log (CSV, ``.ihlog``) into arrays for the fits;
* :mod:`ins_hil.calibration.bench`: the recovery benchmark of ``ins-hil calibrate bench``.
"""
