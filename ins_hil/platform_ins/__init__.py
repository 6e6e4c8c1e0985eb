"""Seed 004: platform (gimballed) INS corrected with gyro precession-angle sensors.

:mod:`.model` the error model, the platform-angle reconstruction, the classical and the reduced
measurements; :mod:`.adaptive` the adaptive Kalman filter; :mod:`.testbed` the simulated comparison.
"""
