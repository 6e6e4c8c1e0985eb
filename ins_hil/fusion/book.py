"""The book's ch. 3 linear models in its own state order (DIGEST_000 §3.1, §3.7, §3.9).

9 states x = [μ; δv; δr] (eq. 3.1) or 12 with the gyro bias δc (eq. 3.40). Used to check
the observability ranks (DIGEST_000 §8 case 26) and the square-root filters on the
book's own matrices; the navigation filter (:mod:`ins_hil.fusion.ekf`) uses the same
conventions with the order [δr, δv, μ, δb_g, δb_a].
"""

from __future__ import annotations

import numpy as np

from ins_hil.fusion.ekf import skew
from ins_hil.types import Vec

Z3 = np.zeros((3, 3))
I3 = np.eye(3)


def phi_9(a_nav: Vec, dt: float) -> Vec:
    """Book eq. (3.2): Φ = [[I,0,0],[CΔt,I,0],[CΔt²/2, IΔt, I]] with C = [ã×] (eq. 3.1)."""
    C = skew(a_nav)
    return np.block([[I3, Z3, Z3], [C * dt, I3, Z3], [C * dt * dt / 2, I3 * dt, I3]])


def phi_12(a_nav: Vec, A: Vec, dt: float) -> Vec:
    """Book eq. (3.41) with A the DCM of eq. (2.5) (A^T maps the body bias to the nav frame)."""
    C = skew(a_nav)
    At = A.T
    return np.block(
        [
            [I3, Z3, Z3, At * dt],
            [C * dt, I3, Z3, C @ At * dt * dt / 2],
            [C * dt * dt / 2, I3 * dt, I3, Z3],
            [Z3, Z3, Z3, I3],
        ]
    )


def h_gps(n: int = 9) -> Vec:
    """Book eq. (3.3) / (3.42): H = [[0, I, 0(,0)], [0, 0, I(,0)]]."""
    H = np.zeros((6, n))
    H[0:3, 3:6] = I3
    H[3:6, 6:9] = I3
    return H


def h_gps_mag_baro(n: int = 9) -> Vec:
    """Book eq. (3.30) / (3.43): z = [−γ̃ (2), v (3), r (3), h (1)], H = [[0_{8×1}, I_8], [0_{1×8}, 1]] (+ zero bias
    columns). The last row picks δr_3, the z (up) position error (the book's Ex 3.2 frame is z-up)."""
    H = np.zeros((9, n))
    H[0:8, 1:9] = np.eye(8)
    H[8, 8] = 1.0
    return H
