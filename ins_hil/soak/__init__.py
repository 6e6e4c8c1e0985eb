"""Soak test: simulated sensors, gateway and ground station as three pinned processes.

:mod:`ins_hil.soak.simproc` (sensors, emission-stamped), :mod:`ins_hil.soak.gateway`
(the real :class:`~ins_hil.runtime.loop.Gateway`; or :mod:`ins_hil.soak.relay`, the null relay in
its place: the platform floor), :mod:`ins_hil.soak.gcs` (pymavlink
ground-station client), :mod:`ins_hil.soak.orchestrate` (start, pin, sample /proc),
:mod:`ins_hil.soak.analysis` (figures and targets), :mod:`ins_hil.soak.report`
(markdown + PNG plots). Command: ``ins-hil soak`` (``scripts/soak``).
"""
