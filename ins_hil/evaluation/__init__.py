"""Evaluation: the filter run against a reference (the simulator's truth, a data set's) and scored.

Above the simulator and the data sets, below the commands: :mod:`ins_hil.evaluation.sim_flight`
(the simulated flight of a gateway config, offline, and the truth of a simulated recording).
"""

from typing import Any


def sim_truth_on_demand(sim: Any, duration: float) -> Any:
    """:func:`ins_hil.evaluation.sim_flight.sim_truth`, imported on the first call: the truth source a replay
    installs (``ins_hil.datasets.ihlog.set_truth_source``) without loading the simulator and the gateway's
    settings for a flight log that never needs them."""
    from ins_hil.evaluation.sim_flight import sim_truth

    return sim_truth(sim, duration)
