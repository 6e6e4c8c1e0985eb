"""Seed 001's conventions at the edges: ENU local frame, right–forward–up body, y-x-z Euler angles.

The core is NED / FRD / Hamilton scalar-first q_nb (ARCHITECTURE.md); seed 001 (Mohamed & Mamas)
works in the ENU l-frame with body axes x right, y forward, z up and R_b^l = R_z(−ψ) R_x(−θ) R_y(−φ)
(eq. 19): φ roll about body y, θ pitch about x, ψ yaw about Up, **counter-clockwise positive**
(nose → West for ψ = +90°; the NED heading is −ψ). These converters translate seed-001 inputs and
outputs; nothing in the core uses them.
"""

from __future__ import annotations

import math

import numpy as np

from ins_hil.types import Vec

# ENU ↔ NED and RFU ↔ FRD are the same axis permutation with a sign on the third axis (its own inverse)
P_SWAP = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def enu_from_ned(v: Vec) -> Vec:
    """A vector's ENU components from its NED ones."""
    return P_SWAP @ np.asarray(v, dtype=float)


def ned_from_enu(v: Vec) -> Vec:
    """A vector's NED components from its ENU ones."""
    return P_SWAP @ np.asarray(v, dtype=float)


def dcm_enu_from_euler_yxz(roll: float, pitch: float, yaw: float) -> Vec:
    """R_b^l of seed 001 eq. (20) (corrected matrix, DIGEST_001_004 §1.4): body RFU → ENU, angles in rad."""
    sf, cf = math.sin(roll), math.cos(roll)
    st, ct = math.sin(pitch), math.cos(pitch)
    sp, cp = math.sin(yaw), math.cos(yaw)
    return np.array(
        [
            [cp * cf - sp * st * sf, -sp * ct, cp * sf + sp * st * cf],
            [sp * cf + cp * st * sf, cp * ct, sp * sf - cp * st * cf],
            [-ct * sf, st, ct * cf],
        ]
    )


def euler_yxz_from_dcm_enu(R: Vec) -> tuple[float, float, float]:
    """(roll φ, pitch θ, yaw ψ) of seed 001 eq. (21) with atan2.

    φ = atan2(−R31, R33), θ = asin(R32), ψ = atan2(−R12, R22)."""
    return (
        math.atan2(-R[2, 0], R[2, 2]),
        math.asin(max(-1.0, min(1.0, float(R[2, 1])))),
        math.atan2(-R[0, 1], R[1, 1]),
    )


def dcm_ned_frd_from_enu_rfu(R_enu: Vec) -> Vec:
    """The project's C_b^n (body FRD → NED) from seed 001's R_b^l (body RFU → ENU)."""
    return P_SWAP @ np.asarray(R_enu, dtype=float) @ P_SWAP


def dcm_enu_rfu_from_ned_frd(C_ned: Vec) -> Vec:
    """Seed 001's R_b^l (body RFU → ENU) from the project's C_b^n (body FRD → NED)."""
    return P_SWAP @ np.asarray(C_ned, dtype=float) @ P_SWAP
