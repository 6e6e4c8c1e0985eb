"""The collaborators of :class:`ins_hil.core.NavCore`, one job each: the measurement contract (``contract``), the
alignment before navigation (``alignment``), GNSS aiding and its reset (``gnss``), the ground-vehicle aids
(``aids``), the learnt baro datum (``baro_datum``) and the delayed-fusion history (``history``). Pure: no I/O,
no clock, no asyncio."""
