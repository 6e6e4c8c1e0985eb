"""The collaborators of :class:`ins_hil.core.NavCore`, one job each: the measurement contract, the ground-vehicle
aids, the learnt baro datum and the delayed-fusion history. Pure: no I/O, no clock, no asyncio."""
