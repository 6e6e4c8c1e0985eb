"""Fusion: the closed-loop error-state EKF behind :class:`ins_hil.core.NavCore`.

Modules
-------
* :mod:`ins_hil.fusion.ekf` — ``FilterConfig`` (state layout 9/12/15/21, noise, numerics,
  ``cov_every``), ``ErrorStateEKF`` (P, error estimate x, ``build_F``, ``predict``,
  ``update(z, H, r_diag)``, ``reset()``), ``StateIndex`` (block offsets).
* :mod:`ins_hil.fusion.measurements` — (z, H) builders: GNSS position/velocity with lever arm,
  baro height, the book's two-component magnetometer (eqs. 3.28–3.38, τ of eq. 3.33),
  non-holonomic constraint, zero velocity.
* :mod:`ins_hil.fusion.sqrt` — book §3.1.2–3.1.3: QR ("Cholesky multiplier") filter, Joseph on
  Cholesky factors, Bierman UD + Thornton, observability rank.
* :mod:`ins_hil.fusion.innovation` — gating (test ratio, NIS) and bounded Sage–Husa adaptive R.
* :mod:`ins_hil.fusion.book` — the book's own 9/12-state Φ and H (eqs. 3.2, 3.3, 3.30, 3.41–3.43).
* :mod:`ins_hil.fusion.continuous_discrete` — linear filters for ẋ = Ax + Bu + ξ with asynchronous
  per-sensor updates: seed 003's continuous–discrete filter (Ṗ = AP + PAᵀ + Q by RK4) or the exact discrete
  one, by name (``make_linear_filter``); analysis tools, not the core's filter.

Conventions (DIGEST_000 §9)
---------------------------
Error state order [δr (NED m), δv (m/s), μ (rad), δb_g (rad/s), δb_a (m/s²), δs_g, δs_a];
δr, δv, δb, δs = true − computed/estimated; Ĉ_b^n = (I + [μ×]) C_b^n; z = measured − predicted.
Feedback: r̂ += δr, v̂ += δv, q ← q(−μ) ⊗ q, b̂ += δb, then x = 0. Biases are body-frame,
subtracted from the increments before the mechanization: Δθ' = (Δθ − b_g Δt)/(1 + s_g).

NavCore API (``ins_hil.core``)
------------------------------
``NavCore(initial: StrapdownState | None = None, config: NavConfig | None = None)``
  ``initial`` is required with ``alignment.mode="given"`` (default); with ``"static"`` it may be None
  (position from the first GNSS fix).
``step(imu: ImuSample) -> NavState``: one IMU interval (mechanization + covariance propagation,
  ground-vehicle aids if enabled). Never blocks, no I/O.
``fuse(meas: AidSample) -> None`` (a GNSS fix, baro, magnetometer, odometer or airspeed sample: any aid source's of
  :mod:`ins_hil.aids`): fused at ``meas.t`` (time of validity):
  queued if in the future, rolled back and re-propagated if older than the current IMU time
  (``delay.compensation``, history ``delay.max_delay`` s).
``state() -> NavState``: q_nb, vel_ned, lat/lon/h, gyro/accel biases, std_pos/vel/att (1σ),
  omega_b/accel_b (compensated), ``aligned`` (False until the alignment is done and yaw σ <
  ``alignment.aligned_yaw_std``), ``test_ratios`` {"gnss_pos", "gnss_vel", "baro", "mag", "nhc", "zupt"}:
  last normalised innovation test ratio (> 1 = rejected).
``drain_events() -> list[FaultEvent]``: GNSS/baro rejections since the last call
  (sensor "gnss"/"baro", mode JUMP, ``cleared=True`` when the sensor is accepted again).
Attributes for tools: ``stats`` (GateStats per kind: accepted/rejected counters), ``adapt``
(Sage–Husa scales), ``kf.P`` (covariance), ``phase`` ("level", "heading", "nav"), ``bg``/``ba``.
"""
