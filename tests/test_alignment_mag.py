"""Magnetic heading at rest (nav.alignment.mag_heading): unit-free, tilt from gravity only."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.nav import alignment
from ins_hil.nav.rotation import dcm_from_quat, euler_from_quat, quat_from_euler

DEG = math.pi / 180
#: a field of 48 µT, 60° dip, 8° east declination (NED, tesla)
REF_T = 48e-6 * np.array(
    (math.cos(60 * DEG) * math.cos(8 * DEG), math.cos(60 * DEG) * math.sin(8 * DEG), math.sin(60 * DEG))
)


def _body(roll: float, pitch: float, yaw: float, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Specific force (m/s²) and field (ref's unit) in body FRD for an attitude at rest."""
    C_bn = dcm_from_quat(quat_from_euler(roll, pitch, yaw))
    return C_bn.T @ np.array((0.0, 0.0, -9.81)), C_bn.T @ ref


@pytest.mark.parametrize("att", [(0, 0, 0), (5, -3, 40), (-20, 15, -170), (30, 25, 95)])
def test_heading_from_field_in_any_unit(att: tuple[float, float, float]) -> None:
    roll, pitch, yaw = (a * DEG for a in att)
    f, m = _body(roll, pitch, yaw, REF_T)
    r, p = alignment.coarse_level(f)
    for ref_unit in (REF_T, REF_T * 1e4, REF_T * 1e9, REF_T / np.linalg.norm(REF_T)):  # T, G, nT, unit
        assert alignment.mag_heading(r, p, m * 1e4, ref_unit) == pytest.approx(yaw, abs=1e-9)  # readings in G


def test_reference_dip_error_moves_no_tilt_and_little_heading() -> None:
    """A reference 6° off in dip: the book's two-vector A puts part of it into roll/pitch; mag_heading
    leaves the tilt to the accelerometer and takes a small heading error only."""
    roll, pitch, yaw = 10 * DEG, -5 * DEG, 60 * DEG
    f, m = _body(roll, pitch, yaw, REF_T)
    wrong = 48e-6 * np.array(
        (math.cos(66 * DEG) * math.cos(8 * DEG), math.cos(66 * DEG) * math.sin(8 * DEG), math.sin(66 * DEG))
    )
    r, p = alignment.coarse_level(f)
    y = alignment.mag_heading(r, p, m, wrong)
    assert (r, p) == pytest.approx((roll, pitch), abs=1e-12)
    assert y == pytest.approx(yaw, abs=1e-9)  # declination unchanged: the heading is exact
    g_ned = np.array((0.0, 0.0, -9.81))
    A = alignment.refined_alignment(np.vstack([g_ned, wrong]), np.vstack([f, m]))
    rb, pb, _ = euler_from_quat(alignment.quat_from_book_A(A))
    assert max(abs(rb - roll), abs(pb - pitch)) > 1 * DEG  # what the equal-weight solution does


def test_book_two_vector_solution_needs_equal_units() -> None:
    """The finding behind mag_heading: A = Z1 Z⁻¹ with a reference in tesla and readings in gauss."""
    roll, pitch, yaw = 0.0, 0.0, 30 * DEG
    f, m = _body(roll, pitch, yaw, REF_T)
    A = alignment.refined_alignment(np.vstack([np.array((0.0, 0.0, -9.81)), REF_T]), np.vstack([f, m * 1e4]))
    rb, pb, _ = euler_from_quat(alignment.quat_from_book_A(A))
    assert max(abs(rb), abs(pb)) > 10 * DEG
    assert alignment.mag_heading(*alignment.coarse_level(f), m * 1e4, REF_T) == pytest.approx(yaw, abs=1e-9)


def test_no_horizontal_field_is_an_error() -> None:
    with pytest.raises(ValueError, match="horizontal"):
        alignment.mag_heading(0.0, 0.0, np.array((0.0, 0.0, 1.0)), REF_T)
