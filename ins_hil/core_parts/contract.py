"""The measurement contract: what an aid hands to the filter update (``NavCore._apply``).

An aid linearises its model at the current nominal state into the innovation, the measurement rows and
the noise (z, H, R), in the spirit of pyins ``Measurement.compute_matrices``; gating, adaptive R, the
update and the feedback are the core's. A new aid is one function that returns a :class:`Measurement`.
"""

from __future__ import annotations

from typing import NamedTuple

from ins_hil.types import Vec


class Measurement(NamedTuple):
    """One linearised measurement.

    kind: names its gate statistics and adaptive R (``gnss_pos``, ``gnss_vel``, ``baro``, ``mag``, ``nhc``,
    ``zupt``); z: innovation, measured − predicted (m,; the aid's units); H: rows (m × n, the error-state
    order of :class:`ins_hil.fusion.ekf.StateIndex`); r: diagonal noise variances (m,; units²);
    gate: the innovation test's gate (σ).
    """

    kind: str
    z: Vec
    H: Vec
    r: Vec
    gate: float
