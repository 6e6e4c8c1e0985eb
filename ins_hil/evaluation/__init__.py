"""Evaluation: the filter run against a reference (the simulator's truth, a data set's) and scored.

Above the simulator and the data sets, below the commands: :mod:`ins_hil.evaluation.sim_flight`
(the simulated flight of a gateway config, offline, and the truth of a simulated recording).
"""
