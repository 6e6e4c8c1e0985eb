"""Error-state extended Kalman filter (closed loop, with feedback and reset).

Error-state conventions (DIGEST_000 §9, the set that makes book ch. 3 consistent):

* attitude: Ĉ_b^n = (I + [μ×]) C_b^n, μ the small rotation of the computed
  attitude relative to the true one (rad, NED axes);
* position/velocity: δr = r_true − r̂ (NED metres), δv = v_true − v̂ (m/s);
* sensor errors: δb = b_true − b̂ (so the compensated rate error is ω̂ − ω = δb_g),
  δs = s_true − ŝ for the scale factors (f̃ = (1 + s) f + b);
* measurements: z = measured − predicted, entering with +H blocks as in
  book eqs. (3.3), (3.30), (3.42), (3.43);
* feedback after an update: r̂ += δr, v̂ += δv, Ĉ ← (I − [μ×]) Ĉ
  (q ← q(−μ) ⊗ q), b̂ += δb, ŝ += δs; then the error estimate is reset to 0.

Linear error dynamics (book eq. 3.1/3.40 extended to NED with Earth rate,
seed 001 eqs. 83–98 reduced to the terms that matter for MEMS):

    δṙ = δv
    δv̇ = [f^n×] μ − (2ω_ie + ω_en) × δv − C δb_a − C diag(f^b) δs_a + (2g/R) δr_D e_D
    μ̇  = −ω_in × μ + C δb_g + C diag(ω^b) δs_g (+ C δG f^b with the g-sensitivity states)
    δḃ = −δb / τ + w      (first-order Gauss–Markov, seed 001 eqs. 87/88)

Discretisation Φ = I + F Δt + ½ (F Δt)² (book eq. 3.2/3.41), propagated every
IMU step or every ``cov_every`` steps with the averaged F. Process noise is
diagonal (the noise is isotropic, so C σ² I C^T = σ² I).

The state layout is configurable (``FilterConfig``): 9 states (book §3.1:
μ, δv, δr), 12 (book §3.3: + gyro bias, ``accel_bias=False``), 15 (default:
+ accelerometer bias), 21 (+ gyro and accelerometer scale factors), + 9 gyro g-sensitivity states,
+ 3 boresight states, + 3 magnetometer hard-iron states. Index order here is
[δr, δv, μ, δb_g, δb_a, δs_g, δs_a, δG, δε, δb_m].

Pure and deterministic: no I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ins_hil.fusion import generated_jacobians as gj
from ins_hil.nav import earth
from ins_hil.settings import check_fields, setting
from ins_hil.types import Vec

DEG = math.pi / 180.0


@dataclass
class FilterConfig:
    """Error-state filter configuration (SI units; noise densities per √Hz).

    gyro_arw: gyro white noise (rad/s/√Hz); accel_vrw: accelerometer white noise (m/s²/√Hz);
    gyro_bias_sigma / accel_bias_sigma: 1-σ of the Gauss–Markov bias (rad/s, m/s²) with
    correlation times gyro_bias_tau / accel_bias_tau (s); scale-factor 1-σ likewise.
    mount_states: 3 extra states at the end, the residual IMU → vehicle boresight rotation seen by the
    non-holonomic constraint (rad, vehicle axes; random walk ``mount_sigma_rw`` rad/√s, initial 1-σ
    ``init_mount``); only NavCore's NHC uses them.
    gyro_gsens: 9 states after the scale factors, the gyro g-sensitivity matrix G (rad/s per m/s², row =
    gyro axis, column = specific-force axis; ω̃ = ω + b_g + G f^b), a random walk ``gsens_sigma_rw``
    (rad/s/(m/s²)/√s) from an initial 1-σ ``init_gsens`` (a MEMS gyro: ~0.01–0.1 °/s/g ≈ 2e-5–2e-4).
    gyro_vib_gain / accel_vib_gain: process noise from the measured vibration, on top of ``gyro_arw`` /
    ``accel_vrw``: the rate and the specific force are known only at the samples, so the angle and the
    velocity change over one IMU interval are uncertain by about the change of the signal across it. Per
    body axis the added variance per step is (gain · dt)² · E[Δx²], with Δx the sample-to-sample change
    of the compensated rate (attitude block) or specific force (velocity block) and E[·] an exponential
    average over ``vib_tau`` s (a car's roof IMU: 3–10 °/s of pitch vibration on rough road, almost none
    at a stop). Rotated to NED (the noise is not isotropic). 0 = off; not with the UD numerics (they take
    a diagonal Q only).
    omega_rv_terms: add the dependence of Earth rate and transport rate on position and velocity to F
    (seed 001 F21/F22/F31/F32, digest 001-K): μ̇ += ∂ω_in/∂r δr + ∂ω_in/∂v δv and
    δv̇ += v × (∂(2ω_ie + ω_en)/∂r δr + ∂ω_en/∂v δv); needs ``earth_terms``; off keeps the reduced model.
    mag_bias: 3 states at the end, the magnetometer hard iron b_m (body FRD, in units of the reference field
    magnitude |m_ref|: m̃_b = C_nb m_ref + b_m, both divided by |m_ref|), δb_m = b_m − b̂_m; a random walk
    ``mag_bias_sigma_rw`` (1/√s) from an initial 1-σ ``init_mag_bias`` (a copter's residual hard iron:
    ~0.1–0.7 of the field). Only NavCore's magnetometer update sees them; a replay's heading-only field
    (``mag_heading_only``, datasets/run.py) has no hard iron left in it for them to estimate.
    wind_states: 2 states at the end, the horizontal wind w (NED north, east; m/s), δw = w − ŵ, a random walk
    ``wind_sigma_rw`` (m/s/√s) from an initial 1-σ ``init_wind`` (m/s); only NavCore's multirotor drag aid
    (``NavConfig.aids.drag``) sees them.
    gap_accel_sigma / gap_rate_sigma: the unknown motion across lost IMU data (a logging gap, a stalled
    link): NavCore coasts the state across the gap at constant velocity and attitude, and the filter adds
    (σ_a Δ)² to each velocity, (σ_a Δ²/2)² to each position and (σ_ω Δ)² to each attitude variance for a
    gap of Δ s (:meth:`ErrorStateEKF.predict_gap`; m/s², rad/s: the acceleration and rate a vehicle may
    hold over a gap of a second or two).
    init_*: initial 1-σ of the error states. cov_every: propagate P every N IMU steps.
    init_accel_sf: per-axis initial 1-σ of the accelerometer scale factors (x, y, z; None = ``init_sf``).
    numerics: "joseph" (sequential scalar Joseph updates, default), "conventional",
    "qr", "cholesky", "ud" (see ``ins_hil.fusion.sqrt``).
    """

    gyro_bias: bool = setting(True, help="estimate the gyro bias (3 states)")
    accel_bias: bool = setting(True, help="estimate the accelerometer bias (3 states)")
    scale_factors: bool = setting(False, help="estimate the gyro and accelerometer scale factors (6 states)")
    gyro_arw: float = setting(0.15 * DEG / 60.0, "rad/s/√Hz", "[0, 1]", "gyro white noise (0: none)")
    accel_vrw: float = setting(70e-6 * 9.80665, "m/s²/√Hz", "[0, 10]", "accelerometer white noise (0: none)")
    gyro_bias_sigma: float = setting(20.0 * DEG / 3600.0, "rad/s", "[0, 1]", "1-σ of the Gauss–Markov gyro bias")
    gyro_bias_tau: float = setting(300.0, "s", "(0, 1e7]", "correlation time of the gyro bias")
    accel_bias_sigma: float = setting(0.5e-3 * 9.80665, "m/s²", "[0, 10]", "1-σ of the Gauss–Markov accelerometer bias")
    accel_bias_tau: float = setting(300.0, "s", "(0, 1e7]", "correlation time of the accelerometer bias")
    gyro_sf_sigma: float = setting(1e-3, "", "[0, 1]", "1-σ of the gyro scale factor")
    accel_sf_sigma: float = setting(2e-3, "", "[0, 1]", "1-σ of the accelerometer scale factor")
    sf_tau: float = setting(3600.0, "s", "(0, 1e7]", "correlation time of the scale factors")
    gyro_gsens: bool = setting(False, help="estimate the gyro g-sensitivity matrix (9 states)")
    gsens_sigma_rw: float = setting(0.0, "rad/s/(m/s²)/√s", "[0, 1]", "random walk of the g-sensitivity")
    init_gsens: float = setting(3e-4, "rad/s/(m/s²)", "(0, 1]", "initial 1-σ of the g-sensitivity")
    mount_states: bool = setting(False, help="estimate the residual IMU → vehicle boresight (3 states; needs nhc)")
    mount_sigma_rw: float = setting(0.0, "rad/√s", "[0, 1]", "random walk of the boresight")
    init_mount: float = setting(1.0 * DEG, "rad", "(0, 3.1416]", "initial 1-σ of the boresight")
    mag_bias: bool = setting(
        False, help="estimate the magnetometer hard iron (3 states; field and reference in one unit)"
    )
    mag_bias_sigma_rw: float = setting(
        1e-4, "|m_ref|/√s", "[0, 1]", "random walk of the hard iron (fraction of the field)"
    )
    init_mag_bias: float = setting(0.3, "|m_ref|", "(0, 10]", "initial 1-σ of the hard iron (fraction of the field)")
    wind_states: bool = setting(False, help="estimate the horizontal wind (2 states; the multirotor drag aid)")
    wind_sigma_rw: float = setting(0.1, "m/s/√s", "[0, 100]", "random walk of the wind")
    init_wind: float = setting(3.0, "m/s", "[0, 100]", "initial 1-σ of the wind")
    gyro_vib_gain: float = setting(
        0.0, "", "[0, 1000]", "attitude process noise from the measured rate change; 0 = off"
    )
    accel_vib_gain: float = setting(
        0.0, "", "[0, 1000]", "velocity process noise from the measured specific-force change; 0 = off"
    )
    vib_tau: float = setting(1.0, "s", "(0, 3600]", "averaging time of the vibration measure")
    gap_accel_sigma: float = setting(
        1.0, "m/s²", "[0, 100]", "unknown acceleration across lost IMU data (velocity σ = it × gap)"
    )
    gap_rate_sigma: float = setting(
        3.0 * DEG, "rad/s", "[0, 10]", "unknown rotation rate across lost IMU data (attitude σ = it × gap)"
    )
    init_pos: float = setting(5.0, "m", "(0, 1e6]", "initial 1-σ position")
    init_vel: float = setting(1.0, "m/s", "(0, 1000]", "initial 1-σ velocity")
    init_att: float = setting(2.0 * DEG, "rad", "(0, 3.1416]", "initial 1-σ roll/pitch")
    init_yaw: float = setting(10.0 * DEG, "rad", "(0, 3.1416]", "initial 1-σ yaw")
    init_gyro_bias: float = setting(0.3 * DEG, "rad/s", "(0, 10]", "initial 1-σ gyro bias")
    init_accel_bias: float = setting(0.3, "m/s²", "(0, 100]", "initial 1-σ accelerometer bias")
    init_sf: float = setting(2e-3, "", "(0, 1]", "initial 1-σ scale factors")
    init_accel_sf: tuple[float, float, float] | None = setting(
        None, "", "(0, 1]", "initial 1-σ accelerometer scale factors x, y, z; not set = init_sf"
    )
    cov_every: int = setting(
        1, "IMU steps", "[1, 1000]", "propagate the covariance every N IMU steps (Python core only)"
    )
    second_order: bool = setting(True, help="second-order transition matrix")
    earth_terms: bool = setting(True, help="Earth rate and transport rate terms in the error model")
    omega_rv_terms: bool = setting(
        False, help="∂ω/∂r, ∂ω/∂v terms of Earth and transport rate in F (seed 001 F21/F22/F31/F32)"
    )
    numerics: str = setting(
        "joseph",
        help="measurement update form (ins_hil.fusion.sqrt)",
        choices=("joseph", "conventional", "qr", "cholesky", "ud"),
    )

    def __post_init__(self) -> None:
        check_fields(self, "FilterConfig")  # each field against its metadata (as [core.nav.filter] is checked)
        if self.vibration and self.numerics == "ud":
            raise ValueError("FilterConfig: the vibration noise (gyro_vib_gain/accel_vib_gain > 0) needs a full "
                             "process-noise root: not with numerics='ud'")  # fmt: skip

    @property
    def vibration(self) -> bool:
        """True if a vibration noise term is on."""
        return self.gyro_vib_gain > 0.0 or self.accel_vib_gain > 0.0


@dataclass
class StateIndex:
    """Start index of each 3-block in the error state (None = not estimated)."""

    n: int
    pos: int = 0
    vel: int = 3
    att: int = 6
    bg: int | None = None
    ba: int | None = None
    sg: int | None = None
    sa: int | None = None
    mnt: int | None = None
    gs: int | None = None  # 9 states: gyro g-sensitivity G row-major
    mb: int | None = None  # magnetometer hard iron (units of |m_ref|, body)
    wind: int | None = None  # 2 states: horizontal wind north, east (m/s)
    #: the aid sources' own blocks (:meth:`ins_hil.aids.AidSource.blocks`), appended last: name → start index
    extra: dict[str, int] = field(default_factory=dict)

    @staticmethod
    def build(cfg: FilterConfig, blocks: tuple[tuple[str, int, float, float], ...] = ()) -> StateIndex:
        """The index of the states ``cfg`` turns on, then the ``blocks`` (name, size, initial σ, random walk
        σ/√s) of the aid sources."""
        k = 9
        bg = ba = sg = sa = None
        if cfg.gyro_bias:
            bg, k = k, k + 3
        if cfg.accel_bias:
            ba, k = k, k + 3
        if cfg.scale_factors:
            sg, k = k, k + 3
            sa, k = k, k + 3
        gs = None
        if cfg.gyro_gsens:
            gs, k = k, k + 9
        mnt = None
        if cfg.mount_states:
            mnt, k = k, k + 3
        mb = None
        if cfg.mag_bias:
            mb, k = k, k + 3
        wind = None
        if cfg.wind_states:
            wind, k = k, k + 2
        extra = {}
        for name, size, _sig, _rw in blocks:
            extra[name], k = k, k + size
        return StateIndex(k, 0, 3, 6, bg, ba, sg, sa, mnt, gs, mb, wind, extra)


def _floats(a: Vec) -> list[float]:
    """The entries of an array (any shape, row by row) or a sequence as Python floats (the generated code's
    scalar arithmetic is faster on floats than on numpy scalars)."""
    return a.ravel().tolist() if isinstance(a, np.ndarray) else [float(x) for x in a]


def skew(a: Vec) -> Vec:
    """[a×] (local fast copy of rotation.skew for floats)."""
    return np.array(((0.0, -a[2], a[1]), (a[2], 0.0, -a[0]), (-a[1], a[0], 0.0)))


#: builds a NamedTuple from a tuple without its generated ``__new__`` (half the cost: a snapshot per IMU step)
_new = tuple.__new__


class EkfSnapshot(NamedTuple):
    """The filter's state at one step (:meth:`ErrorStateEKF.snapshot`): references only; x is zero at a step."""

    P: Vec
    factor: tuple | None
    acc_n: int
    acc_dt: float
    acc_f: Vec
    acc_fb: Vec
    acc_w: Vec
    acc_qv: Vec | None
    vib_prev: tuple[float, ...] | None
    vib_var: tuple[float, ...]


@dataclass
class ErrorStateEKF:
    """Covariance, error-state estimate and the linear models of the closed-loop filter.

    The nominal navigation state (quaternion, velocity, position, biases) lives in
    :class:`ins_hil.core.NavCore`; this class owns P (n×n) and the error estimate x.
    """

    cfg: FilterConfig = field(default_factory=FilterConfig)
    #: the aid sources' own error-state blocks (name, size, initial 1-σ, random-walk σ/√s; StateIndex.extra)
    blocks: tuple[tuple[str, int, float, float], ...] = ()

    def __post_init__(self) -> None:
        c = self.cfg
        self.idx = StateIndex.build(c, self.blocks)
        n = self.idx.n
        self.n = n
        self.x = np.zeros(n)
        sig = np.zeros(n)
        sig[0:3] = c.init_pos
        sig[3:6] = c.init_vel
        sig[6:9] = (c.init_att, c.init_att, c.init_yaw)
        qc = np.zeros(n)  # continuous white-noise spectral densities
        self._tau = np.full(n, np.inf)
        qc[3:6] = c.accel_vrw**2
        qc[6:9] = c.gyro_arw**2
        i = self.idx
        if i.bg is not None:
            sig[i.bg : i.bg + 3] = c.init_gyro_bias
            qc[i.bg : i.bg + 3] = 2.0 * c.gyro_bias_sigma**2 / c.gyro_bias_tau
            self._tau[i.bg : i.bg + 3] = c.gyro_bias_tau
        if i.ba is not None:
            sig[i.ba : i.ba + 3] = c.init_accel_bias
            qc[i.ba : i.ba + 3] = 2.0 * c.accel_bias_sigma**2 / c.accel_bias_tau
            self._tau[i.ba : i.ba + 3] = c.accel_bias_tau
        if i.sg is not None and i.sa is not None:
            sig[i.sg : i.sg + 3] = c.init_sf
            sig[i.sa : i.sa + 3] = c.init_sf if c.init_accel_sf is None else np.asarray(c.init_accel_sf)
            qc[i.sg : i.sg + 3] = 2.0 * c.gyro_sf_sigma**2 / c.sf_tau
            qc[i.sa : i.sa + 3] = 2.0 * c.accel_sf_sigma**2 / c.sf_tau
            self._tau[i.sg : i.sg + 6] = c.sf_tau
        if i.gs is not None:
            sig[i.gs : i.gs + 9] = c.init_gsens
            qc[i.gs : i.gs + 9] = c.gsens_sigma_rw**2
        if i.mnt is not None:
            sig[i.mnt : i.mnt + 3] = c.init_mount
            qc[i.mnt : i.mnt + 3] = c.mount_sigma_rw**2
        if i.mb is not None:
            sig[i.mb : i.mb + 3] = c.init_mag_bias
            qc[i.mb : i.mb + 3] = c.mag_bias_sigma_rw**2
        if i.wind is not None:
            sig[i.wind : i.wind + 2] = c.init_wind
            qc[i.wind : i.wind + 2] = c.wind_sigma_rw**2
        for name, size, sig0, rw in self.blocks:
            k0 = i.extra[name]
            sig[k0 : k0 + size] = sig0
            qc[k0 : k0 + size] = rw**2
        self.qc = qc
        self.P = np.diag(sig**2)
        self._F = np.zeros((n, n))  # its cells: the generated ones (build_F), the rest stays 0
        self._eye = np.eye(n)
        self._g2r = 2.0 * 9.80665 / 6371000.0  # vertical-channel gravity gradient 2g/R (seed 001 eq. 96)
        # the generated F (ins_hil.fusion.generated_jacobians, 15-state layout) placed into this layout: its
        # cells as flat indices of self._F (the bias cells dropped when those states are off)
        i0 = self.idx

        def at(k: int) -> int | None:
            if k < 9:
                return k
            b = i0.bg if k < 12 else i0.ba
            return None if b is None else b + (k - 9) % 3

        cells = [(m, at(r), at(col)) for m, (r, col) in enumerate(gj.F_CELLS)]
        kept = [(m, r, col) for m, r, col in cells if r is not None and col is not None]
        self._gen_idx = np.array([r * n + col for _, r, col in kept])
        self._gen_keep: list[int] | None = None if len(kept) == len(cells) else [m for m, _, _ in kept]
        # the generated scale-factor / g-sensitivity columns (gj.F_SENSOR_CELLS, full layout) placed likewise

        def at_s(k: int) -> int | None:
            if k < gj.NX:
                return at(k)
            for start, lo, hi in ((i0.sg, 15, 18), (i0.sa, 18, 21), (i0.gs, 21, 30)):
                if lo <= k < hi:
                    return None if start is None else start + k - lo
            return None

        cells_s = [(m, at_s(r), at_s(col)) for m, (r, col) in enumerate(gj.F_SENSOR_CELLS)]
        kept_s = [(m, r, col) for m, r, col in cells_s if r is not None and col is not None]
        self._sens_idx = np.array([r * n + col for _, r, col in kept_s]) if kept_s else None
        self._sens_keep = [m for m, _, _ in kept_s]
        self._inv_tau_s = 1.0 / c.sf_tau
        # the generated ∂ω/∂r, ∂ω/∂v terms (gj.F_OMEGA_RV_CELLS, 15-state layout: rows and columns < 9): added to
        # the base cells they share, stored into the others
        base = {(r, col) for r, col in gj.F_CELLS}
        self._rv_idx = np.array([r * n + col for r, col in gj.F_OMEGA_RV_CELLS])
        self._rv_shared = np.array([(r, col) in base for r, col in gj.F_OMEGA_RV_CELLS])
        self._inv_tau_g = 1.0 / self._tau[i0.bg] if i0.bg is not None else 0.0
        self._inv_tau_a = 1.0 / self._tau[i0.ba] if i0.ba is not None else 0.0
        self._qd_cache: tuple[float, Vec] = (-1.0, np.zeros((n, n)))
        self._diag = np.arange(n) * (n + 1)
        # accumulation for cov_every > 1
        self._acc_n = 0
        self._acc_dt = 0.0
        self._acc_f = np.zeros(3)
        self._acc_w = np.zeros(3)
        self._acc_fb = np.zeros(3)
        self._acc_qv: Vec | None = None
        ia, iv = self.idx.att, self.idx.vel
        self._vib_idx = np.array([r * n + col for k in (ia, iv) for r in range(k, k + 3) for col in range(k, k + 3)])
        # vibration noise (FilterConfig.gyro_vib_gain/accel_vib_gain): the previous compensated rate and
        # specific force (body) and E[Δω²], E[Δf²] per body axis, as immutable 6-tuples (kept by the snapshots)
        self.vib_prev: tuple[float, ...] | None = None
        self.vib_var: tuple[float, ...] = (0.0,) * 6
        self._vib = c.vibration
        self.n_predict = 0
        self.factor: tuple | None = None  # square-root/UD factor when numerics is qr/cholesky/ud
        if c.numerics in ("qr", "cholesky", "ud"):
            from ins_hil.fusion import sqrt as sq

            self.factor = sq.factor_from_cov(c.numerics, self.P)

    def snapshot(self) -> EkfSnapshot:
        """P, its factor, the ``cov_every`` accumulators and the vibration-noise state by reference: they are
        replaced, never mutated in place, so a snapshot stays valid (delayed fusion takes one per step)."""
        return _new(EkfSnapshot, (
            self.P, self.factor, self._acc_n, self._acc_dt, self._acc_f, self._acc_fb, self._acc_w, self._acc_qv,
            self.vib_prev, self.vib_var,
        ))  # fmt: skip

    def restore(self, d: EkfSnapshot) -> None:
        """Put back the state of a :meth:`snapshot`, with a zero error estimate (after a feedback)."""
        (self.P, self.factor, self._acc_n, self._acc_dt, self._acc_f, self._acc_fb, self._acc_w, self._acc_qv,
         self.vib_prev, self.vib_var) = d  # fmt: skip
        self.x = np.zeros(self.n)

    # ------------------------------------------------------------------ prediction
    def set_state_sigma(self, block: str, sigma: Vec | float) -> None:
        """Reset the variance of one block (e.g. "att" after an alignment); clears its correlations."""
        k = int(getattr(self.idx, block))
        P = self.P.copy()  # P is replaced, never mutated in place (NavCore keeps references in snapshots)
        s = np.broadcast_to(np.asarray(sigma, dtype=np.float64), (3,))
        P[k : k + 3, :] = 0.0
        P[:, k : k + 3] = 0.0
        P[k : k + 3, k : k + 3] = np.diag(s**2)
        self._reset_P(P)

    def _reset_P(self, P: Vec) -> None:
        """Install a new covariance (and the factor of the square-root numerics) outside the update/predict."""
        self.P = P
        if self.factor is not None:
            from ins_hil.fusion import sqrt as sq

            self.factor = sq.factor_from_cov(self.cfg.numerics, self.P)

    def level_tilt(self, C_bn: Vec, f_b: Vec, sigma: float) -> None:
        """Tilt prior after accelerometer levelling at rest (book §4.1.1): the levelled attitude makes
        the computed horizontal specific force zero, so the tilt error absorbs the horizontal
        accelerometer error instead of being independent of it.

        From δv̇ = [f^n×] μ − C δb_a − C diag(f^b) δs_a (module doc), zero horizontal δv̇ at the levelling
        gives μ_NE = A x + ε with x the accelerometer error states (bias, scale factor), A = −M⁻¹ B,
        M = [f^n×] (rows N, E; columns μ_N, μ_E), B the x columns; ε ~ N(0, ``sigma``²) (rad) is what the
        levelling leaves (window noise, drift since the window). The yaw row and x keep their variances;
        μ_NE's correlations with x (and through x with everything else) follow. ``C_bn`` is the levelled
        attitude (with its yaw as the filter now holds it: the tilt is fixed in NED, x in the body). Without
        accelerometer error states there is nothing to correlate and the tilt keeps its prior.
        After a two-vector (magnetometer) alignment the relation is approximate: gravity dominates its tilt."""
        i = self.idx
        cols: list[int] = []
        blocks: list[Vec] = []
        f_n = C_bn @ f_b
        F15 = gj.F(C_bn, _floats(f_n), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, 0.0, 0.0)  # the generated δv̇ rows
        if i.ba is not None:
            cols += range(i.ba, i.ba + 3)
            blocks.append(F15[3:5, 12:15])  # −Ĉ
        if i.sa is not None:
            cols += range(i.sa, i.sa + 3)
            blocks.append(gj.F_sensor(C_bn, _floats(f_b), (0.0, 0.0, 0.0), 0.0)[3:5, 18:21])  # −Ĉ diag(f^b), generated
        if not cols:
            return
        P = self.P.copy()  # replaced, never mutated in place
        r = slice(6, 8)
        P[r, :] = 0.0
        P[:, r] = 0.0
        M = F15[3:5, 6:8]  # [f^n×] rows N, E; columns μ_N, μ_E
        A = -np.linalg.solve(M, np.hstack(blocks))
        X = np.array(cols)
        P[r, :] = A @ P[X, :]
        P[:, r] = P[r, :].T
        P[r, r] = A @ P[np.ix_(X, X)] @ A.T + np.eye(2) * sigma**2
        self._reset_P(P)

    def build_F(self, C_bn: Vec, f_ned: Vec, w_ie: Vec, w_en: Vec, f_b: Vec, w_b: Vec, lat: float, h: float) -> Vec:
        """Continuous error-dynamics matrix F (n×n) at the current nominal state (see module doc): the entries
        of the generated derivation (``ins_hil.fusion.generated_jacobians``: [f×] in δv̇/μ (book eq. 3.1),
        −[(2ω_ie + ω_en)×] on δv, −[ω_in×] on μ, 2g/R on δr_D, ±C on the biases) in one vectorised store, then
        the generated scale-factor and g-sensitivity columns (``gj.F_sensor_values``) when those states are on,
        then the generated ∂ω/∂r, ∂ω/∂v terms (``omega_rv_terms``, ``gj.F_omega_rv_values``)."""
        F = self._F
        if self.cfg.earth_terms:
            wie, wen, g2r = _floats(w_ie), _floats(w_en), self._g2r
        else:
            wie = wen = [0.0, 0.0, 0.0]
            g2r = 0.0
        vals = gj.F_values(_floats(C_bn), _floats(f_ned), wie, wen, self._inv_tau_g, self._inv_tau_a, g2r)
        keep = self._gen_keep
        F.put(self._gen_idx, vals if keep is None else [vals[k] for k in keep])
        if self._sens_idx is not None:  # scale factors (C diag(ω^b), −C diag(f^b)), g-sensitivity (C δG f^b)
            sv = gj.F_sensor_values(_floats(C_bn), _floats(f_b), _floats(w_b), self._inv_tau_s)
            F.put(self._sens_idx, [sv[k] for k in self._sens_keep])
        if self.cfg.omega_rv_terms and self.cfg.earth_terms:
            # the velocity from the transport rate (the mechanization's ω_en, v_D taken as 0: seed 001 eqs. 94-98)
            M, N = earth.radii(lat)
            rm, rn = M + h, N + h
            add = gj.F_omega_rv_values(wie, lat, rm, rn, -wen[1] * rm, wen[0] * rn)
            idx = self._rv_idx
            F.put(idx, np.where(self._rv_shared, F.take(idx), 0.0) + np.array(add))
        return F

    def predict(
        self, dt: float, C_bn: Vec, f_ned: Vec, w_ie: Vec, w_en: Vec, f_b: Vec, w_b: Vec, lat: float, h: float
    ) -> None:
        """Time update over one IMU interval dt (s); every ``cov_every`` calls the covariance is
        propagated with F at the current state and the specific force/rates averaged over the block."""
        ce = self.cfg.cov_every
        qv = self._vibration_noise(dt, C_bn, w_b, f_b) if self._vib else None
        if ce > 1:
            if qv is not None:
                acc = self._acc_qv
                self._acc_qv = qv if acc is None else acc + qv
            self._acc_n += 1
            self._acc_dt += dt
            self._acc_f = self._acc_f + f_ned
            if self.idx.sg is not None or self.idx.gs is not None:
                self._acc_fb = self._acc_fb + f_b
                self._acc_w = self._acc_w + w_b
            if self._acc_n < ce:
                return
            k = self._acc_n
            dt = self._acc_dt
            f_ned = self._acc_f / k
            f_b = self._acc_fb / k
            w_b = self._acc_w / k
            self._acc_n = 0
            self._acc_dt = 0.0
            self._acc_f = np.zeros(3)
            self._acc_fb = np.zeros(3)
            self._acc_w = np.zeros(3)
            if qv is not None:
                qv = self._acc_qv
                self._acc_qv = None
        F = self.build_F(C_bn, f_ned, w_ie, w_en, f_b, w_b, lat, h)
        self.propagate(self._transition(F, dt), self.qc * dt, dt, qv)

    def _transition(self, F: Vec, dt: float) -> Vec:
        """Φ = I + FΔt (+ F²Δt²/2 with ``second_order``; book eq. 3.2)."""
        Phi = F * dt
        Phi += self._eye
        if self.cfg.second_order:
            Phi += (0.5 * dt * dt) * (F @ F)
        return Phi

    def predict_gap(self, gap: float, C_bn: Vec, f_ned: Vec, w_ie: Vec, w_en: Vec, lat: float, h: float) -> None:
        """Time update across ``gap`` s of lost IMU data, the nominal state coasted at constant velocity and
        attitude (specific force ``f_ned`` = −g, NED): F at that state (book eq. 3.2, second order), the sensor
        noise over the gap and the unknown motion of the gap (``gap_accel_sigma`` σ_a, ``gap_rate_sigma`` σ_ω):
        σ_v = σ_a Δ, σ_r = σ_a Δ²/2, σ_att = σ_ω Δ per axis, Δ = ``gap``."""
        F = self.build_F(C_bn, f_ned, w_ie, w_en, C_bn.T @ f_ned, np.zeros(3), lat, h)
        i = self.idx
        sa, sw = self.cfg.gap_accel_sigma * gap, self.cfg.gap_rate_sigma * gap
        qd = self.qc * gap
        qd[i.pos : i.pos + 3] += (0.5 * sa * gap) ** 2
        qd[i.vel : i.vel + 3] += sa * sa
        qd[i.att : i.att + 3] += sw * sw
        self.propagate(self._transition(F, gap), qd)

    def _vibration_noise(self, dt: float, C_bn: Vec, w_b: Vec, f_b: Vec) -> Vec:
        """The attitude and velocity noise of one step from the vibration (``FilterConfig.gyro_vib_gain`` /
        ``accel_vib_gain``): updates E[Δω²] ((rad/s)²) and E[Δf²] ((m/s²)²), body axes, with this step's
        changes and returns [C diag((g_ω dt)² E[Δω²]) C^T, C diag((g_f dt)² E[Δf²]) C^T] (2×3×3, NED; rad², (m/s)²).
        Scalar floats on the hot path."""
        x0, x1, x2 = float(w_b[0]), float(w_b[1]), float(w_b[2])
        x3, x4, x5 = float(f_b[0]), float(f_b[1]), float(f_b[2])
        prev = self.vib_prev
        v0, v1, v2, v3, v4, v5 = self.vib_var
        if prev is not None:
            b = min(1.0, dt / self.cfg.vib_tau)
            p0, p1, p2, p3, p4, p5 = prev
            d0, d1, d2, d3, d4, d5 = x0 - p0, x1 - p1, x2 - p2, x3 - p3, x4 - p4, x5 - p5
            v0, v1, v2 = v0 + b * (d0 * d0 - v0), v1 + b * (d1 * d1 - v1), v2 + b * (d2 * d2 - v2)
            v3, v4, v5 = v3 + b * (d3 * d3 - v3), v4 + b * (d4 * d4 - v4), v5 + b * (d5 * d5 - v5)
            self.vib_var = (v0, v1, v2, v3, v4, v5)
        self.vib_prev = (x0, x1, x2, x3, x4, x5)
        gw = self.cfg.gyro_vib_gain * dt
        gf = self.cfg.accel_vib_gain * dt
        gw, gf = gw * gw, gf * gf
        d = np.array(((gw * v0, gw * v1, gw * v2), (gf * v3, gf * v4, gf * v5)))
        return np.matmul(C_bn * d[:, None, :], C_bn.T)

    def propagate(self, Phi: Vec, qd: Vec, dt: float | None = None, q_vib: Vec | None = None) -> None:
        """P ← Φ P Φ^T + diag(qd) (book eq. 3.7/3.19), or the factor form of the configured numerics.
        With ``dt`` the diagonal matrix diag(qd) = diag(qc) dt is cached (fixed IMU rate). ``q_vib``
        (2×3×3, NED) is added to the attitude and velocity blocks (the vibration noise)."""
        self.n_predict += 1
        if self.factor is not None:
            from ins_hil.fusion import sqrt as sq

            root = None
            if q_vib is not None:
                # a wider root [diag(√qd), E] (qr_predict stacks it beside Φ p): E E^T puts q_att, q_vel in
                # their blocks; E from the eigen-decomposition of each 3×3 (PSD, possibly rank-deficient)
                n = self.n
                E = np.zeros((n, 6))
                for k, j, q in ((self.idx.att, 0, q_vib[0]), (self.idx.vel, 3, q_vib[1])):
                    lam, V = np.linalg.eigh(q)
                    E[k : k + 3, j : j + 3] = V * np.sqrt(np.clip(lam, 0.0, None))
                root = np.hstack([np.diag(np.sqrt(qd)), E])
            self.factor = sq.factor_predict(self.factor, Phi, qd, root)
            self.P = sq.factor_cov(self.factor)
            return
        P = np.dot(np.dot(Phi, self.P), Phi.T)
        if dt is not None:
            if self._qd_cache[0] != dt:
                self._qd_cache = (dt, np.diag(qd))
            P += self._qd_cache[1]
        else:
            P.flat[self._diag] += qd
        if q_vib is not None:  # P is the new array from the products above, not a snapshot's
            P.flat[self._vib_idx] += q_vib.ravel()
        self.P = P

    # ------------------------------------------------------------------ update
    def innovation_cov(self, H: Vec, R: Vec) -> Vec:
        """S = H P H^T + R."""
        return H @ self.P @ H.T + R

    def update(self, z: Vec, H: Vec, r_diag: Vec) -> None:
        """Measurement update with residual z (measured − predicted, before the current x is applied),
        rows H (m×n) and diagonal noise variances r_diag (m,).

        Default: sequential scalar updates in Joseph form (book eq. 3.16–3.18); other
        numerics from :mod:`ins_hil.fusion.sqrt`. The error estimate accumulates in ``x``
        until :meth:`reset` (feedback) is called.
        """
        numerics = self.cfg.numerics
        if numerics == "joseph":
            x, P = self.x, self.P
            for j in range(len(z)):
                h = H[j]
                ph = P @ h
                s = float(h @ ph) + float(r_diag[j])
                k = ph / s
                x = x + k * (float(z[j]) - float(h @ x))
                kc = k[:, None]  # outer products by broadcasting: the same numbers as np.outer, less overhead
                A = self._eye - kc * h
                P = A @ P @ A.T + float(r_diag[j]) * (kc * k)
            self.x = x
            self.P = 0.5 * (P + P.T)
            return
        from ins_hil.fusion import sqrt as sq

        if numerics == "conventional":
            self.x, self.P = sq.conventional_update(self.x, self.P, z, H, np.diag(r_diag))
            return
        if self.factor is None:
            self.factor = sq.factor_from_cov(numerics, self.P)
        self.x, self.factor = sq.factor_update(self.factor, self.x, z, H, r_diag)
        self.P = sq.factor_cov(self.factor)

    def reset(self) -> Vec:
        """Return the error estimate for feedback and zero it (closed-loop reset, DIGEST_000 §10 item 23)."""
        x = self.x
        self.x = np.zeros(self.n)
        return x

    def std(self) -> Vec:
        """1-σ of every error state."""
        return np.sqrt(np.abs(self.P.diagonal()))
