"""DCM integration by Poisson's equation (seed 003 §3.4, DIGEST_001_004 §3.4 and §6 case 24)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from ins_hil.nav import poisson
from ins_hil.nav.rotation import dcm_from_quat, quat_angle_between, quat_from_rotvec, skew


def test_scalar_form_corrected_equals_matrix_form_and_printed_does_not() -> None:
    rng = np.random.default_rng(21)
    C = poisson.dcm_yup(*rng.uniform(-1, 1, 3))
    w = rng.normal(size=3)
    np.testing.assert_allclose(poisson.poisson_rhs_scalar(C, w), C @ skew(w), atol=1e-15)
    np.testing.assert_allclose(poisson.poisson_rhs(C, w), C @ skew(w), atol=1e-15)
    bad = poisson.poisson_rhs_printed(C, w) - C @ skew(w)
    assert abs(bad[1, 0]) > 1e-3 and abs(bad[2, 1]) > 1e-3  # the two index typos ċ21, ċ32


def test_seed003_dcm_corrected_is_orthogonal_and_angles_round_trip() -> None:
    """Case 24 (003-A): corrected C is orthogonal; the angle formulas (with arctg) recover the inputs."""
    psi, th, ga = 0.3, 0.2, 0.1
    C = poisson.dcm_yup(psi, th, ga)
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(C) == pytest.approx(1.0)
    np.testing.assert_allclose(poisson.angles_yup(C), (psi, th, ga), atol=1e-12)
    # the printed matrix (line 688) is not orthogonal: element (1,2) of C Cᵀ is 0.4296
    cp, sp, ct, st, cg, sg = math.cos(psi), math.sin(psi), math.cos(th), math.sin(th), math.cos(ga), math.sin(ga)
    printed = np.array(
        [
            [ct * cp, cg * cp * st + sg * sp, sg * cp * st + cg * sp],
            [st, cg * ct, sg * ct],
            [-ct * sp, cg * sp * st + sg * cp, -sg * sp * st + cg * cp],
        ]
    )
    assert (printed @ printed.T)[0, 1] == pytest.approx(0.4296, abs=1e-4)


def test_exact_increment_is_the_matrix_exponential() -> None:
    rng = np.random.default_rng(22)
    for mag in (1e-9, 1e-4, 0.3, 1.0):
        th = rng.normal(size=3)
        th *= mag / np.linalg.norm(th)
        np.testing.assert_allclose(poisson.dcm_increment(th, 0), expm(skew(th)), atol=1e-14)
        np.testing.assert_allclose(poisson.dcm_increment(th, 0), dcm_from_quat(quat_from_rotvec(th)), atol=1e-14)
    with pytest.raises(ValueError, match="order"):
        poisson.dcm_increment(np.zeros(3), 5)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_truncated_poisson_update_converges_with_its_order(order: int) -> None:
    """Constant rate for 1 s: the truncated series update has global error O(h^order)."""
    w = np.array([0.4, -0.3, 0.8])
    exact = expm(skew(w))
    errs = []
    for n in (40, 80):
        C = poisson.integrate_dcm(np.eye(3), np.tile(w / n, (n, 1)), order)
        errs.append(np.linalg.norm(C - exact))
    assert errs[0] / errs[1] == pytest.approx(2.0**order, rel=0.2)


def test_orthonormalize_restores_orthogonality_and_is_nearest() -> None:
    rng = np.random.default_rng(23)
    R = expm(skew(rng.normal(size=3)))
    Cn = R + 1e-3 * rng.normal(size=(3, 3))
    O = poisson.orthonormalize(Cn)
    np.testing.assert_allclose(O @ O.T, np.eye(3), atol=1e-14)
    assert np.linalg.norm(O - Cn) <= np.linalg.norm(R - Cn) + 1e-15
    C = poisson.integrate_dcm(np.eye(3), np.tile([0.05, 0.02, -0.04], (500, 1)), order=1, renorm_every=10)
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-3)


def test_poisson_behind_the_quaternion_interface() -> None:
    """The registry's 'poisson' (order 0) reproduces the exact rotation for a constant rate."""
    from ins_hil.nav.attitude import make_attitude

    alg = make_attitude("poisson", order=0)
    q = np.array([1.0, 0, 0, 0])
    w = np.array([0.2, 0.5, -0.1])
    for _ in range(100):
        q = alg.step_increment(q, w * 0.01, 0.01)
    assert quat_angle_between(q, quat_from_rotvec(w)) < 1e-12
