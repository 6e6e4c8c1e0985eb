"""Inertial and magnetic sensor calibration (book §4.2, DIGEST_000 §4.4–4.5), pure.

Measurement model of one triad (book eq. 4.10/4.11 for accelerometers,
4.22/4.23 for rate gyros; nonlinearity neglected)::

    m = A x + b + η,   A = S A_ε,   b = S b_a,   S = diag(1 + s)

with ``x`` the true specific force (m/s², body FRD) or angular rate (rad/s),
``m`` the sensor output in the same unit. The twelve unknowns
``X = [A1 A2 A3 b1 b2 b3]^T`` (rows of A, then b) are estimated by least
squares via QR factorisation (eqs. 4.12–4.15) from a multi-position static test
(accelerometers) or a rate-table test (gyros, Table 4.1). The adequacy figure
is the book's measurement "deviation" ``dev = ‖z2‖/‖z1‖·100 %`` (eq. 4.17).
``A`` is split as ``A = I + εB ≈ (I + εB_sym)(I + εB_skew)`` (eqs. 4.18–4.21):
the symmetric part holds scale factors and non-orthogonality, the skew part
the small rotation μ of the triad against the calibration table.

Magnetometers (book summary 4.3.2, MEMS magnetometers): hard and soft iron
``m = A x + b`` with ``x`` the field in body axes, found by an ellipsoid fit of
a rotation sequence (``A`` is taken symmetric, so the residual rotation of the
triad is left to the alignment).

Sign convention: the book's reference gravity is ``g_ref = [0 0 9.81]`` (its
accelerometer reads +g on the up axis); in this project's body FRD a level
accelerometer reads ``f = [0, 0, −g]``, so the references here are
``f = C_x(φ1) C_y(φ2) [0, 0, −g]`` with the book's ``C_ix``/``C_iy``. The
table-4.1 rate vectors are ``C_x(φ1) C_y(φ2) [0, 0, ±ω_ref]`` exactly as printed
(the rate axis is body +z at zero tilt, i.e. down in FRD).

Calibration file (TOML or JSON, chosen by suffix; written by ``ins-hil calibrate``,
read and written by :mod:`ins_hil.calibration.files`; this module only validates and
builds its tables, :meth:`SensorCalibration.from_dict` / :meth:`SensorCalibration.to_dict`)::

    format = "ins_hil-calibration"      # required
    version = 1                         # required
    imu_id = 0                          # optional: applies to this IMU only
    created = "2026-11-23T09:00:00Z"    # optional, informational
    source = "bench.csv"                # optional, informational

    [accel]                             # optional section, same for [gyro], [mag]
    unit = "m/s^2"                      # "m/s^2", "rad/s", "T" (checked)
    matrix = [[1.001, 0.0002, -0.0001], [..], [..]]   # A of m = A x + b
    bias = [0.19, -0.05, 0.11]          # b of m = A x + b, in ``unit``
    dev_percent = 0.01                  # optional, eq. 4.17
    cond = 3.4                          # optional, cond(R0), eq. 4.16
    n_equations = 48                    # optional

    [noise.gyro]                        # optional, Allan-variance figures
    random_walk = 4.4e-5                # rad/s/√Hz (ARW) or m/s²/√Hz (VRW)
    bias_instability = 4.8e-5           # rad/s or m/s²
    rate_random_walk = 1e-6             # rad/s/√s or m/s²/√s

The gateway corrects every sample by ``x = A⁻¹ (m − b)``; for IMU increments
over an interval dt: ``Δθ' = A_g⁻¹ (Δθ − b_g dt)``, ``Δv' = A_a⁻¹ (Δv − b_a dt)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg

from ins_hil.nav import earth
from ins_hil.types import ImuFlags, ImuSample, MagSample, Vec

FORMAT_NAME = "ins_hil-calibration"
FORMAT_VERSION = 1
SENSORS = ("accel", "gyro", "mag")
UNITS = {"accel": "m/s^2", "gyro": "rad/s", "mag": "T"}
N_UNKNOWNS = 12  # X = [A1 A2 A3 b1 b2 b3]^T, book §4.2.1


class CalibrationError(ValueError):
    """Bad or insufficient calibration data or file; the message says what is missing."""


# ---------------------------------------------------------------------------
# book geometry: C_ix, C_iy, the 16 accelerometer positions, Table 4.1
# ---------------------------------------------------------------------------


def book_C_x(phi: float) -> Vec:
    """The book's C_ix (§4.2.1): tilt by φ (rad) about body X."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def book_C_y(phi: float) -> Vec:
    """The book's C_iy (§4.2.1): tilt by φ (rad) about body Y."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def tilt_dcm(phi1: float, phi2: float) -> Vec:
    """C_x(φ1) C_y(φ2): table frame → body for tilts φ1 about X and φ2 about Y (rad).

    Equals C_n^b of ZYX Euler angles roll = φ1, pitch = φ2, yaw = 0.
    """
    return book_C_x(phi1) @ book_C_y(phi2)


#: book §4.2.1: φ1(i) = φ2(i) = i·45°, i = 1..8; first 8 about X, then 8 about Y (rad)
BOOK_ACCEL_POSITIONS: tuple[tuple[float, float], ...] = tuple(
    [(i * math.pi / 4, 0.0) for i in range(1, 9)] + [(0.0, i * math.pi / 4) for i in range(1, 9)]
)

#: book Table 4.1: (φ1 tilt about X, φ2 tilt about Y) of the 7 rate-table positions (rad)
TABLE_4_1_TILTS: tuple[tuple[float, float], ...] = (
    (0.0, 0.0),
    (0.0, -math.pi / 4),
    (0.0, math.pi / 4),
    (0.0, math.pi / 2),
    (-math.pi / 4, 0.0),
    (math.pi / 4, 0.0),
    (math.pi / 2, 0.0),
)


def table_4_1(omega_ref: float = 1.0) -> Vec:
    """Reference rate vectors of Table 4.1 (7, 3) for +ω_ref: C_x(φ1) C_y(φ2) [0 0 ω_ref]^T."""
    return np.array([tilt_dcm(p1, p2) @ np.array([0.0, 0.0, omega_ref]) for p1, p2 in TABLE_4_1_TILTS])


def accel_references(tilts: Sequence[tuple[float, float]], g: float = earth.G0) -> Vec:
    """Reference specific forces (M, 3) in body FRD, m/s², at static tilts (φ1, φ2) in rad.

    ``f = C_x(φ1) C_y(φ2) [0, 0, −g]`` (the book's a_ix = C_ix g_ref with g_ref
    pointing along the sensor's up axis, here FRD so −g).
    """
    return np.array([tilt_dcm(p1, p2) @ np.array([0.0, 0.0, -g]) for p1, p2 in tilts])


def gyro_references(
    tilts: Sequence[tuple[float, float]],
    rates: Sequence[float],
    latitude: float | None = None,
) -> Vec:
    """Rate-table reference rates (rad/s, body FRD) for every rate, position and sense.

    Order: for each ω in ``rates`` (rad/s), for each tilt, +ω then −ω (book: N = 7·2
    experiments per rate, Table 4.1). The table axis is body +z at zero tilt.
    With ``latitude`` (rad) the Earth-rate component along the (vertical) table
    axis is added; the horizontal part averages out over whole revolutions.
    """
    w_axis = 0.0 if latitude is None else -earth.OMEGA_E * math.sin(latitude)  # along +z = down
    out = []
    for w in rates:
        for p1, p2 in tilts:
            c = tilt_dcm(p1, p2)[:, 2]
            out.append(c * (w + w_axis))
            out.append(c * (-w + w_axis))
    return np.array(out)


# ---------------------------------------------------------------------------
# least squares by QR (eqs. 4.12–4.17) and the decomposition (4.18–4.21)
# ---------------------------------------------------------------------------


def design_matrix(refs: Vec) -> Vec:
    """A_Σ (3M × 12) of eq. 4.12 from M reference vectors (M, 3): blocks A_ix of §4.2.1."""
    refs = np.asarray(refs, dtype=np.float64)
    m = len(refs)
    a = np.zeros((3 * m, N_UNKNOWNS))
    for axis in range(3):
        a[axis::3, 3 * axis : 3 * axis + 3] = refs
        a[axis::3, 9 + axis] = 1.0
    return a


@dataclass
class LsqResult:
    """QR least-squares solution of B_Σ = A_Σ X + η (eqs. 4.14–4.17)."""

    x: Vec  # (12,)
    dev_percent: float  # eq. 4.17
    cond: float  # cond(R0) = √cond(A_Σ^T A_Σ), eq. 4.16
    residual_rms: float  # ‖z2‖ / √(rows − 12), in the measurement unit
    n_equations: int


def solve_qr(a_sigma: Vec, b_sigma: Vec) -> LsqResult:
    """X = R0⁻¹ z1 with A_Σ = Q^T R, Q B_Σ = [z1; z2] (book eqs. 4.14, 4.15).

    Raises CalibrationError when A_Σ has fewer rows than unknowns or is rank deficient.
    """
    a_sigma = np.asarray(a_sigma, dtype=np.float64)
    b_sigma = np.asarray(b_sigma, dtype=np.float64).ravel()
    rows, n = a_sigma.shape
    if not (np.all(np.isfinite(a_sigma)) and np.all(np.isfinite(b_sigma))):
        raise CalibrationError("references or measurements contain NaN/inf")
    if rows < n:
        raise CalibrationError(f"{rows} equations for {n} unknowns: need at least {n} (book §4.2.1, n_e ≥ 12)")
    # numpy: A = Q_np R, so the book's Q is Q_np^T and Q B = Q_np^T B
    q, r = np.linalg.qr(a_sigma, mode="complete")
    r0 = r[:n, :n]
    d = np.abs(np.diag(r0))
    if d.min() <= 1e-10 * d.max():
        raise CalibrationError(
            "the reference vectors do not determine all 12 unknowns (rank-deficient A_Σ): "
            "the positions must not all lie in one plane — use tilts about both X and Y"
        )
    z = q.T @ b_sigma
    z1, z2 = z[:n], z[n:]
    x = scipy.linalg.solve_triangular(r0, z1)
    n1 = float(np.linalg.norm(z1))
    n2 = float(np.linalg.norm(z2))
    sv = np.linalg.svd(r0, compute_uv=False)
    return LsqResult(
        x=x,
        dev_percent=100.0 * n2 / n1 if n1 > 0 else math.inf,
        cond=float(sv[0] / sv[-1]),
        residual_rms=n2 / math.sqrt(rows - n) if rows > n else 0.0,
        n_equations=rows,
    )


@dataclass
class Decomposition:
    """Book eqs. 4.13 (split) and 4.18–4.21 of a 3×3 matrix A."""

    scale: Vec  # diag(S) = [a11, a22, a33]
    misalignment: Vec  # A_ε = S⁻¹ A
    sym: Vec  # I + εB_sym
    skew: Vec  # I + εB_skew
    mu: Vec  # [μ1, μ2, μ3] (rad) of eq. 4.21


def decompose(a: Vec) -> Decomposition:
    """S = diag(a11, a22, a33), A_ε = S⁻¹A; A = I + εB, εB split into symmetric/skew parts."""
    a = np.asarray(a, dtype=np.float64)
    s = np.diag(a).copy()
    eb = a - np.eye(3)
    sym = 0.5 * (eb + eb.T)
    sk = 0.5 * (eb - eb.T)
    k = np.eye(3) + sk
    # eq. 4.21: I + εB_skew ≅ [[1, μ3, −μ2], [−μ3, 1, μ1], [μ2, −μ1, 1]]
    mu = np.array([k[1, 2], k[2, 0], k[0, 1]])
    return Decomposition(s, a / s[:, None], np.eye(3) + sym, k, mu)


@dataclass
class TriadFit:
    """Result of a triad calibration: m = A x + b (book eq. 4.11/4.23)."""

    matrix: Vec
    bias: Vec
    dev_percent: float
    cond: float
    residual_rms: float
    n_equations: int

    @property
    def decomposition(self) -> Decomposition:
        return decompose(self.matrix)

    @property
    def bias_book(self) -> Vec:
        """b_a = S⁻¹ b (book §4.2.1): the bias before the scale factor."""
        return self.bias / np.diag(self.matrix)


def fit_triad(refs: Vec, measured: Vec) -> TriadFit:
    """Estimate A, b of m = A x + b from reference vectors (M, 3) and mean outputs (M, 3)."""
    refs = np.asarray(refs, dtype=np.float64)
    measured = np.asarray(measured, dtype=np.float64)
    if refs.shape != measured.shape or refs.ndim != 2 or refs.shape[1] != 3:
        raise CalibrationError(f"references {refs.shape} and measurements {measured.shape} must both be (M, 3)")
    res = solve_qr(design_matrix(refs), measured.ravel())
    a = res.x[:9].reshape(3, 3)
    return TriadFit(a, res.x[9:].copy(), res.dev_percent, res.cond, res.residual_rms, res.n_equations)


# ---------------------------------------------------------------------------
# static/constant-rate steps from a log: checks, means, detection
# ---------------------------------------------------------------------------


@dataclass
class StepLimits:
    """Checks on the samples of one step (defaults suit a MEMS IMU at 50–1000 Hz).

    max_std: per-axis sample standard deviation (unit of the signal) above which
    the step is taken as moving; max_drift: allowed change of the mean between
    the first and second half of the step; min_samples: fewest samples per step;
    saturation: |value| at or above which a sample counts as saturated (0 = off).
    """

    max_std: float
    max_drift: float
    min_samples: int = 50
    saturation: float = 0.0


# std limits leave room for consumer MEMS noise at 1 kHz (e.g. 400 µg/√Hz → 0.12 m/s² per sample);
# the drift limit catches slow creep that a std test misses
ACCEL_LIMITS = StepLimits(max_std=0.2, max_drift=0.01)  # m/s²
GYRO_LIMITS = StepLimits(max_std=0.05, max_drift=0.002)  # rad/s


def step_means(
    values: Vec,
    labels: Vec,
    limits: StepLimits,
    what: str,
    flags: Vec | None = None,
    saturated_bit: int = 0,
) -> tuple[list[int], Vec, Vec]:
    """Mean of ``values`` (N, 3) over each step label ≥ 0 (labels < 0 are transitions).

    Returns (sorted labels, means (M, 3), sample counts (M,)). Raises
    CalibrationError naming the step if it has too few samples, saturated samples
    (``flags & saturated_bit`` or |value| ≥ limits.saturation), or shows motion
    (std above limits.max_std or drift of the mean above limits.max_drift).
    """
    values = np.asarray(values, dtype=np.float64)
    labels = np.asarray(labels).astype(np.int64)
    if values.ndim != 2 or values.shape[1] != 3 or len(labels) != len(values):
        raise CalibrationError(f"{what}: values must be (N, 3) with one step label per sample")
    if not np.all(np.isfinite(values)):
        bad = int(np.count_nonzero(~np.isfinite(values).all(axis=1)))
        raise CalibrationError(f"{what}: {bad} samples are NaN/inf; clean the log first")
    uniq = sorted(int(u) for u in np.unique(labels) if u >= 0)
    means = np.zeros((len(uniq), 3))
    counts = np.zeros(len(uniq), dtype=np.int64)
    for j, lab in enumerate(uniq):
        v = values[labels == lab]
        n = len(v)
        if n < limits.min_samples:
            raise CalibrationError(f"{what} step {lab}: only {n} samples, need at least {limits.min_samples}")
        if flags is not None and saturated_bit:
            ns = int(np.count_nonzero(np.asarray(flags)[labels == lab] & saturated_bit))
            if ns:
                raise CalibrationError(
                    f"{what} step {lab}: {ns} of {n} samples flagged saturated; the sensor range is "
                    "exceeded, re-record this step (a saturated mean would bias the calibration)"
                )
        if limits.saturation > 0:
            ns = int(np.count_nonzero((np.abs(v) >= limits.saturation).any(axis=1)))
            if ns:
                raise CalibrationError(
                    f"{what} step {lab}: {ns} of {n} samples at or beyond the range ±{limits.saturation:g}; "
                    "re-record this step within range"
                )
        sd = v.std(axis=0)
        if sd.max() > limits.max_std:
            ax = "xyz"[int(sd.argmax())]
            raise CalibrationError(
                f"{what} step {lab}: motion during the step (std {sd.max():.3g} on {ax} > {limits.max_std:g}); "
                "hold the sensor still (or the rate constant) for the whole step"
            )
        h = n // 2
        drift = np.abs(v[h:].mean(axis=0) - v[:h].mean(axis=0))
        if drift.max() > limits.max_drift:
            ax = "xyz"[int(drift.argmax())]
            raise CalibrationError(
                f"{what} step {lab}: the mean moved by {drift.max():.3g} on {ax} between the halves of "
                f"the step (> {limits.max_drift:g}); the sensor moved or the rate changed during the step"
            )
        means[j] = v.mean(axis=0)
        counts[j] = n
    return uniq, means, counts


def detect_steps(values: Vec, dt: float, window: float = 1.0, max_std: float = 0.05, min_duration: float = 5.0) -> Vec:
    """Label quiet segments (moving per-axis std ≤ max_std over ``window`` s) lasting ≥ ``min_duration`` s.

    Returns labels (N,): 0, 1, 2, … for the segments in time order, −1 elsewhere.
    Vectorised (running sums). Used when a log has no ``step`` column.
    """
    values = np.asarray(values, dtype=np.float64)
    n = len(values)
    w = max(2, round(window / dt))
    labels = np.full(n, -1, dtype=np.int64)
    if n < w:
        return labels
    v = values - values.mean(axis=0)
    c1 = np.vstack([np.zeros(3), np.cumsum(v, axis=0)])
    c2 = np.vstack([np.zeros(3), np.cumsum(v * v, axis=0)])
    s1 = c1[w:] - c1[:-w]
    s2 = c2[w:] - c2[:-w]
    var = np.maximum(s2 / w - (s1 / w) ** 2, 0.0)
    quiet_win = (np.sqrt(var) <= max_std).all(axis=1)  # window k covers samples k..k+w-1
    # a sample is quiet when every window containing it is quiet (erodes the edges)
    bad = np.concatenate([[0], np.cumsum(~quiet_win)])
    lo = np.clip(np.arange(n) - w + 1, 0, len(quiet_win))
    hi = np.clip(np.arange(n) + 1, 0, len(quiet_win))
    quiet = (bad[hi] - bad[lo] == 0) & (hi > lo)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], quiet.astype(np.int8), [0]])))
    lab = 0
    for a, b in zip(edges[::2], edges[1::2]):
        if (b - a) * dt >= min_duration:
            labels[a:b] = lab
            lab += 1
    return labels


def _match_plan(what: str, labels: list[int], refs: Vec) -> Vec:
    if len(labels) != len(refs):
        raise CalibrationError(
            f"{what}: the log has {len(labels)} steps but the plan has {len(refs)} positions; "
            "every planned position must be recorded (check the step column or the step detection)"
        )
    return refs


#: a fitted scale factor further than this from 1 means wrong references or units, not a sensor error
MAX_SCALE_ERROR = 0.2
#: a deviation (eq. 4.17) above this means the plan does not match the log (the book's worst was 4 %)
MAX_DEV_PERCENT = 10.0


def _checked(what: str, fit: TriadFit) -> TriadFit:
    s = np.diag(fit.matrix)
    j = int(np.argmax(np.abs(s - 1.0)))
    if abs(s[j] - 1.0) > MAX_SCALE_ERROR:
        raise CalibrationError(
            f"{what}: fitted scale factor {s[j]:.4g} on {'xyz'[j]} is implausible (|s − 1| > {MAX_SCALE_ERROR}); "
            "the reference values (table rates, gravity) or the units of the log are wrong"
        )
    if fit.dev_percent > MAX_DEV_PERCENT:
        raise CalibrationError(
            f"{what}: deviation dev = {fit.dev_percent:.2f} % (eq. 4.17) exceeds {MAX_DEV_PERCENT} %; the steps do "
            "not match the plan's positions (order, angles or signs)"
        )
    return fit


def _calibrate_triad(
    what: str, values: Vec, labels: Vec, refs: Vec, limits: StepLimits, flags: Vec | None, bit: int, need: str
) -> TriadFit:
    refs = np.asarray(refs, dtype=np.float64)
    if len(refs) < 4:
        raise CalibrationError(
            f"{what}: {len(refs)} steps give {3 * len(refs)} equations for 12 unknowns; need at least {need}"
        )
    labs, means, _ = step_means(values, labels, limits, what, flags, bit)
    return _checked(what, fit_triad(_match_plan(what, labs, refs), means))


def calibrate_accel(
    accel: Vec, labels: Vec, refs: Vec, limits: StepLimits = ACCEL_LIMITS, flags: Vec | None = None
) -> TriadFit:
    """Multi-position static accelerometer calibration (book §4.2.1).

    accel: (N, 3) mean specific force per sample (m/s², Δv/dt); labels: step of each
    sample (−1 = moving); refs: (M, 3) reference specific force of step 0..M−1.
    Needs ≥ 4 positions not in one plane (12 unknowns, book n_e ≥ 12).
    """
    need = "4 positions not in one plane (the book uses 16: 8 about X, 8 about Y)"
    return _calibrate_triad("accelerometer", accel, labels, refs, limits, flags, int(ImuFlags.ACCEL_SATURATED), need)


def calibrate_gyro(
    gyro: Vec, labels: Vec, refs: Vec, limits: StepLimits = GYRO_LIMITS, flags: Vec | None = None
) -> TriadFit:
    """Rate-table gyro calibration (book §4.2.2, Table 4.1); arguments as :func:`calibrate_accel`
    with gyro rates (rad/s) and reference rates (rad/s, e.g. :func:`gyro_references`)."""
    need = "4 rate steps (the book uses 7 positions × ±ω = 14 per rate)"
    return _calibrate_triad("gyro", gyro, labels, refs, limits, flags, int(ImuFlags.GYRO_SATURATED), need)


# ---------------------------------------------------------------------------
# magnetometer: hard/soft iron by ellipsoid fit
# ---------------------------------------------------------------------------


@dataclass
class MagFit:
    """m = A x + b with A symmetric positive definite (soft iron) and b (hard iron, T)."""

    matrix: Vec
    bias: Vec
    radius: float  # field magnitude after correction (T)
    residual_rms: float  # rms of |x| − radius after correction (T)
    coverage: float  # smallest eigenvalue of the direction covariance (1/3 = full sphere)


def fit_ellipsoid(m: Vec, field_norm: float | None = None, min_coverage: float = 0.02) -> MagFit:
    """Hard/soft-iron calibration from a rotation sequence of raw field vectors m (N, 3), T.

    Algebraic least-squares quadric fit x^T M x + 2 n^T x + d = 0 (smallest right
    singular vector of the normalised design matrix); centre b = −M⁻¹ n; the
    correction W = A⁻¹ = sqrt(M/k) scaled to ``field_norm`` (or, without it, to the
    volume-equivalent radius of the ellipsoid). Raises CalibrationError for too few
    samples, too little rotation (directions not spread over the sphere) or a
    quadric that is not an ellipsoid.
    """
    m = np.asarray(m, dtype=np.float64)
    if m.ndim != 2 or m.shape[1] != 3:
        raise CalibrationError(f"magnetometer: samples must be (N, 3), got {m.shape}")
    if len(m) < 30:
        raise CalibrationError(f"magnetometer: only {len(m)} samples; need at least 30 spread over all orientations")
    if not np.all(np.isfinite(m)):
        raise CalibrationError("magnetometer: the samples contain NaN/inf")
    c0 = m.mean(axis=0)
    sc = float(np.abs(m - c0).max())
    if sc <= 0:
        raise CalibrationError("magnetometer: all samples are identical; rotate the sensor")
    p = (m - c0) / sc
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    d = np.column_stack([x * x, y * y, z * z, 2 * y * z, 2 * x * z, 2 * x * y, 2 * x, 2 * y, 2 * z, np.ones(len(p))])
    _, sv, vt = np.linalg.svd(d, full_matrices=False)
    if sv[-2] <= 1e-9 * sv[0]:
        raise CalibrationError(
            "magnetometer: the rotation sequence does not determine the ellipsoid "
            "(samples on a plane or a curve); rotate through all orientations"
        )
    a, bb, c, f, g, h, pp, q, r, dd = vt[-1]
    mm = np.array([[a, h, g], [h, bb, f], [g, f, c]])
    nn = np.array([pp, q, r])
    if np.linalg.det(mm) < 0:
        mm, nn, dd = -mm, -nn, -dd
    ev = np.linalg.eigvalsh(mm)
    if ev.min() <= 0:
        raise CalibrationError("magnetometer: the fitted quadric is not an ellipsoid; rotate through all orientations")
    centre = -np.linalg.solve(mm, nn)
    k = float(centre @ mm @ centre - dd)
    if k <= 0:
        raise CalibrationError("magnetometer: the fitted quadric is not an ellipsoid (degenerate data)")
    w_unit = scipy.linalg.sqrtm(mm / k).real  # maps centred (normalised) data onto the unit sphere
    w_unit = 0.5 * (w_unit + w_unit.T)
    b = c0 + sc * centre
    u = (p - centre) @ w_unit.T  # unit-sphere directions
    dirs = u / np.linalg.norm(u, axis=1)[:, None]
    coverage = float(np.linalg.eigvalsh(dirs.T @ dirs / len(dirs)).min())
    if coverage < min_coverage:
        raise CalibrationError(
            f"magnetometer: the samples cover too little of the sphere (spread {coverage:.3f} < {min_coverage}; "
            "1/3 is a full sphere); rotate the sensor through all orientations, e.g. full turns about each axis"
        )
    radius = field_norm if field_norm is not None else sc / float(np.prod(np.linalg.eigvalsh(w_unit))) ** (1.0 / 3.0)
    w = w_unit * (radius / sc)  # x = W (m − b), |x| = radius
    xcal = (m - b) @ w.T
    resid = np.linalg.norm(xcal, axis=1) - radius
    return MagFit(np.linalg.inv(w), b, float(radius), float(np.sqrt(np.mean(resid**2))), coverage)


# ---------------------------------------------------------------------------
# the calibration file and its application at run time
# ---------------------------------------------------------------------------


@dataclass
class TriadCalibration:
    """Calibration of one triad: output m = A x + b; corrected x = A⁻¹ (m − b).

    ``matrix`` A (3×3, dimensionless), ``bias`` b in the sensor's SI unit.
    """

    matrix: Vec
    bias: Vec
    unit: str = ""
    dev_percent: float = math.nan
    cond: float = math.nan
    n_equations: int = 0
    inverse: Vec = field(init=False, repr=False)
    coeffs: tuple[float, ...] = field(init=False, repr=False)  # A⁻¹ row-major, then b (hot path)

    def __post_init__(self) -> None:
        self.matrix = np.asarray(self.matrix, dtype=np.float64).reshape(3, 3)
        self.bias = np.asarray(self.bias, dtype=np.float64).reshape(3)
        self.inverse = np.linalg.inv(self.matrix)
        self.coeffs = tuple(float(v) for v in self.inverse.ravel()) + tuple(float(v) for v in self.bias)

    def correct(self, m: Vec) -> Vec:
        """x = A⁻¹ (m − b) for one vector (3,) or rows (N, 3)."""
        return (np.asarray(m) - self.bias) @ self.inverse.T

    @classmethod
    def from_fit(cls, fit: TriadFit | MagFit, unit: str) -> TriadCalibration:
        if isinstance(fit, TriadFit):
            return cls(fit.matrix, fit.bias, unit, fit.dev_percent, fit.cond, fit.n_equations)
        return cls(fit.matrix, fit.bias, unit)


def _correct_inc(c: tuple[float, ...], inc: Vec, dt: float) -> Vec:
    """A⁻¹ (inc − b dt) with A⁻¹, b packed in ``c`` (scalar floats: numpy's per-call cost dominates for 3-vectors)."""
    x, y, z = float(inc[0]) - c[9] * dt, float(inc[1]) - c[10] * dt, float(inc[2]) - c[11] * dt
    return np.array([c[0] * x + c[1] * y + c[2] * z, c[3] * x + c[4] * y + c[5] * z, c[6] * x + c[7] * y + c[8] * z])


@dataclass
class SensorCalibration:
    """Calibration of one IMU (+ magnetometer): what the gateway loads at start.

    ``imu_id`` None applies to any IMU. ``noise`` holds Allan-variance figures per
    sensor (informational, for filter tuning).
    """

    accel: TriadCalibration | None = None
    gyro: TriadCalibration | None = None
    mag: TriadCalibration | None = None
    imu_id: int | None = None
    noise: dict[str, dict[str, float]] = field(default_factory=dict)
    created: str = ""
    source: str = ""

    def applies_to(self, imu_id: int) -> bool:
        """True when this calibration is for IMU ``imu_id``."""
        return self.imu_id is None or self.imu_id == imu_id

    def apply(self, imu: ImuSample) -> ImuSample:
        """The sample with corrected increments: Δθ' = A_g⁻¹(Δθ − b_g dt), Δv' = A_a⁻¹(Δv − b_a dt).

        A sample of another IMU (``imu.imu_id`` ≠ ``imu_id``) is returned unchanged: a calibration
        belongs to one sensor. Hot path: scalar arithmetic on coefficients cached at construction.
        """
        if self.imu_id is not None and imu.imu_id != self.imu_id:
            return imu
        dt = imu.dt
        dth = imu.dtheta if self.gyro is None else _correct_inc(self.gyro.coeffs, imu.dtheta, dt)
        dv = imu.dvel if self.accel is None else _correct_inc(self.accel.coeffs, imu.dvel, dt)
        return ImuSample(
            t=imu.t,
            dt=dt,
            dtheta=dth,
            dvel=dv,
            imu_id=imu.imu_id,
            seq=imu.seq,
            temperature=imu.temperature,
            flags=imu.flags,
            t_arrival_ns=imu.t_arrival_ns,
        )

    def apply_mag(self, mag: MagSample) -> MagSample:
        """The magnetometer sample with hard/soft iron removed."""
        if self.mag is None:
            return mag
        return MagSample(
            t=mag.t, field_b=self.mag.correct(mag.field_b), source=mag.source, t_arrival_ns=mag.t_arrival_ns
        )

    def merged(self, other: SensorCalibration) -> SensorCalibration:
        """This calibration with every section present in ``other`` replaced by other's."""
        noise = {**self.noise, **other.noise}
        return SensorCalibration(
            accel=other.accel or self.accel,
            gyro=other.gyro or self.gyro,
            mag=other.mag or self.mag,
            imu_id=other.imu_id if other.imu_id is not None else self.imu_id,
            noise=noise,
            created=other.created or self.created,
            source=", ".join(s for s in dict.fromkeys([self.source, other.source]) if s),
        )

    # --- (de)serialisation -------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"format": FORMAT_NAME, "version": FORMAT_VERSION}
        if self.imu_id is not None:
            d["imu_id"] = self.imu_id
        if self.created:
            d["created"] = self.created
        if self.source:
            d["source"] = self.source
        for name in SENSORS:
            tc: TriadCalibration | None = getattr(self, name)
            if tc is None:
                continue
            sec: dict[str, Any] = {
                "unit": UNITS[name],
                "matrix": [[float(v) for v in row] for row in tc.matrix],
                "bias": [float(v) for v in tc.bias],
            }
            if math.isfinite(tc.dev_percent):
                sec["dev_percent"] = float(tc.dev_percent)
            if math.isfinite(tc.cond):
                sec["cond"] = float(tc.cond)
            if tc.n_equations:
                sec["n_equations"] = int(tc.n_equations)
            d[name] = sec
        if self.noise:
            d["noise"] = {
                k: {kk: float(vv) for kk, vv in v.items() if math.isfinite(vv)} for k, v in self.noise.items()
            }
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "calibration") -> SensorCalibration:
        """Validate and build; CalibrationError names the bad key."""
        if d.get("format") != FORMAT_NAME:
            raise CalibrationError(f"{where}: key 'format' must be {FORMAT_NAME!r}, got {d.get('format')!r}")
        if d.get("version") != FORMAT_VERSION:
            raise CalibrationError(f"{where}: key 'version' must be {FORMAT_VERSION}, got {d.get('version')!r}")
        known = {"format", "version", "imu_id", "created", "source", "noise", *SENSORS}
        extra = sorted(set(d) - known)
        if extra:
            raise CalibrationError(f"{where}: unknown key(s) {extra}; known: {sorted(known)}")
        imu_id = d.get("imu_id")
        if imu_id is not None and (not isinstance(imu_id, int) or isinstance(imu_id, bool) or imu_id < 0):
            raise CalibrationError(f"{where}: key 'imu_id' must be a non-negative integer, got {imu_id!r}")
        out = cls(imu_id=imu_id, created=str(d.get("created", "")), source=str(d.get("source", "")))
        for name in SENSORS:
            if name in d:
                setattr(out, name, _triad_from_dict(d[name], f"{where}: [{name}]", UNITS[name]))
        noise = d.get("noise", {})
        if not isinstance(noise, Mapping):
            raise CalibrationError(f"{where}: key 'noise' must be a table")
        for k, v in noise.items():
            if not isinstance(v, Mapping) or not all(_is_number(x) for x in v.values()):
                raise CalibrationError(f"{where}: [noise.{k}] must map names to numbers")
            out.noise[str(k)] = {str(kk): float(vv) for kk, vv in v.items()}
        return out


def _is_number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(float(x))


def _triad_from_dict(sec: Any, where: str, unit: str) -> TriadCalibration:
    if not isinstance(sec, Mapping):
        raise CalibrationError(f"{where} must be a table")
    known = {"unit", "matrix", "bias", "dev_percent", "cond", "n_equations"}
    extra = sorted(set(sec) - known)
    if extra:
        raise CalibrationError(f"{where}: unknown key(s) {extra}; known: {sorted(known)}")
    if sec.get("unit", unit) != unit:
        raise CalibrationError(f"{where}: key 'unit' must be {unit!r}, got {sec.get('unit')!r}")
    mat = sec.get("matrix")
    if (
        not isinstance(mat, Sequence)
        or len(mat) != 3
        or not all(isinstance(r, Sequence) and len(r) == 3 and all(_is_number(v) for v in r) for r in mat)
    ):
        raise CalibrationError(f"{where}: key 'matrix' must be a 3×3 array of finite numbers, got {mat!r}")
    b = sec.get("bias")
    if not isinstance(b, Sequence) or len(b) != 3 or not all(_is_number(v) for v in b):
        raise CalibrationError(f"{where}: key 'bias' must be 3 finite numbers, got {b!r}")
    a = np.array(mat, dtype=np.float64)
    if np.linalg.cond(a) > 1e6:
        raise CalibrationError(f"{where}: key 'matrix' is singular or nearly so (cond {np.linalg.cond(a):.3g})")
    for k in ("dev_percent", "cond"):
        if k in sec and not _is_number(sec[k]):
            raise CalibrationError(f"{where}: key {k!r} must be a number")
    return TriadCalibration(
        a,
        np.array(b, dtype=np.float64),
        unit,
        float(sec.get("dev_percent", math.nan)),
        float(sec.get("cond", math.nan)),
        int(sec.get("n_equations", 0)),
    )
