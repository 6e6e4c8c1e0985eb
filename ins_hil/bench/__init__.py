"""Benchmarks behind the ``ins-hil bench-*`` commands: the measurements and their Markdown reports.

:mod:`.core` (Python core vs C reference core: per step, per GNSS update, callgrind, accuracy),
:mod:`.drivers` (decode cost, loss-free frame rate on a pty and vcan, 1 % corruption) and :mod:`.fdi`
(Monte-Carlo FDI: failure modes, false alarms, navigation after isolation, cost per call, GNSS/baro drift).
The commands in :mod:`ins_hil.commands` parse arguments, print and write the files."""
