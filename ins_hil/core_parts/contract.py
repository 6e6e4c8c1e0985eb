"""The measurement contract: what an aid hands to the filter update (``NavCore._apply``).

An aid linearises its model at the current nominal state into the innovation, the measurement rows and
the noise (z, H, R), in the spirit of pyins ``Measurement.compute_matrices``; gating, adaptive R, the
update and the feedback are the core's. A new aid is one module of :mod:`ins_hil.aids` whose model returns a
:class:`Measurement`.

The core's input contract (:func:`check_imu`; an aid sample's is its source's ``check``,
:meth:`ins_hil.aids.AidSource.check`): ``NavCore.step`` / ``fuse`` refuse, with a one-line ValueError, a sample
they cannot integrate or fuse (non-finite values or times, ``dt`` ≤ 0).
"""

from __future__ import annotations

from typing import NamedTuple

from ins_hil.types import ImuSample, Vec


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


# -- the input contract of NavCore.step / fuse -------------------------------------------------------------
# The core refuses what it cannot integrate or fuse, in one line (ValueError), even though the runtime's
# validation boundary (ins_hil.validation) filters every sample before it: a caller that feeds the core
# directly (a replay, a tool, a test) gets the refusal instead of a NaN state, a math-domain ValueError deep
# in the filter or a ZeroDivisionError. Limits are structural only (finite, dt > 0); the physical ranges are
# the validation boundary's.

_INF = float("inf")


def _vec3(v: object, what: str) -> tuple[float, float, float]:
    """Three finite floats from ``v`` (numpy array or sequence), else ValueError naming ``what``."""
    try:
        x0, x1, x2 = (float(x) for x in v)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        raise ValueError(f"{what} = {v!r}: must be 3 finite numbers") from None
    if not (abs(x0) < _INF and abs(x1) < _INF and abs(x2) < _INF):
        raise ValueError(f"{what} = ({x0!r}, {x1!r}, {x2!r}): must be 3 finite numbers")
    return x0, x1, x2


def check_imu(imu: ImuSample) -> None:
    """Refuse (ValueError, one line) an IMU sample the core cannot integrate: ``t`` not finite, ``dt`` not a
    finite number > 0 (s), ``dtheta`` / ``dvel`` not 3 finite numbers. The hot path: comparisons only."""
    dt, t = imu.dt, imu.t
    try:
        a0, a1, a2 = imu.dtheta.tolist()
        v0, v1, v2 = imu.dvel.tolist()
    except (AttributeError, TypeError, ValueError):
        a0, a1, a2 = _vec3(imu.dtheta, "NavCore.step: imu.dtheta")
        v0, v1, v2 = _vec3(imu.dvel, "NavCore.step: imu.dvel")
    # NaN fails every comparison: one test for the good case
    if (
        0.0 < dt < _INF and abs(t) < _INF
        and abs(a0) < _INF and abs(a1) < _INF and abs(a2) < _INF
        and abs(v0) < _INF and abs(v1) < _INF and abs(v2) < _INF
    ):  # fmt: skip
        return
    if not 0.0 < dt < _INF:
        raise ValueError(f"NavCore.step: imu.dt = {dt!r}: must be a finite number > 0 (s)")
    if not abs(t) < _INF:
        raise ValueError(f"NavCore.step: imu.t = {t!r}: must be a finite time (s)")
    _vec3(imu.dtheta, "NavCore.step: imu.dtheta")
    _vec3(imu.dvel, "NavCore.step: imu.dvel")
