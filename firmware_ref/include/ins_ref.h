/*
 * ins_ref.h - ins_hil C99 fixed-step reference navigation core.
 *
 * What a flight computer would run: NED strapdown mechanization on IMU
 * increments, a 15-state error-state EKF (GNSS position/velocity and baro
 * updates, Joseph form, sequential scalar), and the redundant-gyro parity
 * check (FDI) with a projector computed offline from the sensor geometry.
 *
 * Rules: C99; the step period is fixed at initialisation; no malloc, no
 * recursion, no global mutable state (every function works on a caller-owned
 * context struct); all loops are bounded by compile-time constants (the one
 * exception, ins_core_run, by the caller's log length n).
 *
 * Scalar type: `ins_real` is double, or float when compiled with
 * -DINS_REF_FLOAT (a compile-time switch; the whole library follows it).
 *
 * Conventions (as ins_hil, see ARCHITECTURE.md / DIGEST_000 section 9):
 * NED navigation frame, body FRD, Hamilton scalar-first quaternion q_nb
 * (body -> NED), SI units (rad, m, m/s, s); latitude/longitude in rad,
 * ellipsoidal height in m.
 *
 * Error state (15, or 21 with the scale factors): x = [dr_N dr_E dr_D | dv_N dv_E dv_D | psi_N psi_E psi_D |
 * dbg_x dbg_y dbg_z | dba_x dba_y dba_z (| dsg_x dsg_y dsg_z | dsa_x dsa_y dsa_z)] with dr, dv = true - computed
 * (m, m/s, NED), psi the attitude error with C_hat = (I + [psi x]) C_true
 * (DIGEST_000 section 9), dbg/dba = true - estimated gyro/accel bias (body,
 * rad/s and m/s^2), dsg/dsa = true - estimated gyro/accel scale factor (w~ = (1 + s) w + b). The filter feeds back and resets x after each measurement
 * group. Model, gates and feedback mirror ins_hil.fusion.ekf / ins_hil.core.NavCore
 * (checked to 1e-9 relative by tests/test_firmware.py).
 */
#ifndef INS_REF_H
#define INS_REF_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#ifdef INS_REF_FLOAT
typedef float ins_real;
#define INS_REF_SCALAR_BITS 32
#else
typedef double ins_real;
#define INS_REF_SCALAR_BITS 64
#endif
/* Geodetic position and time stay double in both builds: a 32-bit latitude
 * has ~0.3 m resolution, coarser than one 200 Hz position increment (as in
 * flight firmware that keeps lat/lon in double or integers). */
typedef double ins_pos;

#define INS_NX 21 /* error states at most: 15, + 6 scale factors (ins_ekf_t.nx) */

/* ---------------------------------------------------------------- quaternions */

/* r = p (x) q, Hamilton product, scalar first (book eq. 2.16 in matrix form). r may alias neither. */
void ins_quat_mul(const ins_real p[4], const ins_real q[4], ins_real r[4]);
/* Normalise to unit norm with q0 >= 0. */
void ins_quat_normalize(ins_real q[4]);
/* Exact quaternion of a rotation vector (rad). */
void ins_quat_from_rotvec(const ins_real v[3], ins_real q[4]);
/* C_b^n from q_nb (row-major 3x3); the book's A = C_n^b is its transpose (eq. 2.5). */
void ins_dcm_from_quat(const ins_real q[4], ins_real c[9]);
/* Quaternion from C_b^n (Shepperd's method, q0 >= 0). */
void ins_quat_from_dcm(const ins_real c[9], ins_real q[4]);
/* Roll, pitch, yaw (ZYX, rad) from q_nb (book eq. 2.11 with atan2). */
void ins_euler_from_quat(const ins_real q[4], ins_real rpy[3]);
/* q_nb from roll, pitch, yaw (standard ZYX half-angle formula, DIGEST_000 section 1.3). */
void ins_quat_from_euler(const ins_real rpy[3], ins_real q[4]);

/* ------------------------------------------------------ book attitude update */

/* The book's rotational mechanization (DIGEST_000 section 2.2): rate samples
 * w_i at a fixed step, quasi-coordinates by the quadratic spline (eq. 2.19)
 * and the update quaternion eq. 2.18, lam_i = lam_{i-1} (x) dlam_i (eq. 2.15).
 * Start-up (the book is silent, DIGEST_000 section 10 item 6): step 1 uses
 * dt*w_1, step 2 the trapezoid dt/2*(w_1+w_2), then eq. 2.19; the previous
 * quasi-coordinate of step 1 is 0. lam is not normalised (the book's 1/12
 * form is not unit norm); read it through ins_book_att_quat(). */
typedef struct {
    ins_real lam[4];    /* quaternion (body -> fixed frame), unnormalised */
    ins_real w1[3];     /* w(t_{i-1}) */
    ins_real w2[3];     /* w(t_{i-2}) */
    ins_real th_prev[3]; /* quasi-coordinates of the previous step */
    ins_real dt;
    uint32_t n;         /* steps taken */
} ins_book_att_t;

void ins_book_att_init(ins_book_att_t *a, const ins_real q0[4], ins_real dt);
/* One step with the body rate w(t_i) (rad/s) sampled at the end of the step (eq. 2.19, then 2.18). */
void ins_book_att_step(ins_book_att_t *a, const ins_real w[3]);
/* One step of eq. 2.18 with given quasi-coordinates th_i (rad), e.g. exact gyro increments. */
void ins_book_att_step_th(ins_book_att_t *a, const ins_real th[3]);
/* Normalised copy of the current quaternion. */
void ins_book_att_quat(const ins_book_att_t *a, ins_real q[4]);

/* -------------------------------------------------------------- mechanization */

/* NED strapdown on increments: the same equations, in the same order, as
 * ins_hil.nav.mechanization.StrapdownNED.step (rotation vector with coning
 * correction, sculling, Earth rate, transport rate, Coriolis, normal gravity,
 * trapezoidal position). */
typedef struct {
    ins_real q[4];      /* q_nb */
    ins_real v[3];      /* v_ned, m/s */
    ins_pos lat, lon, h;
    double t;           /* sensor time, s */
    ins_real dt;        /* fixed step, s */
    ins_real dth_prev[3], dv_prev[3];
    int have_prev;
    int coning, sculling, earth_rate;
    uint32_t renorm_every, n;
    ins_real f_ned[3];     /* last specific force, NED, m/s^2 */
    ins_real omega_ie[3];  /* last Earth rate, NED, rad/s */
    ins_real omega_en[3];  /* last transport rate, NED, rad/s */
} ins_mech_t;

void ins_mech_init(ins_mech_t *m, const ins_real q[4], const ins_real v[3], ins_pos lat, ins_pos lon, ins_pos h,
                   double t, ins_real dt);
/* Advance by one fixed step with delta angle dth (rad, FRD) and delta velocity dv (m/s, FRD). */
void ins_mech_step(ins_mech_t *m, const ins_real dth[3], const ins_real dv[3]);

/* ------------------------------------------------------------------------ EKF */

/* Mirrors ins_hil.fusion.ekf.FilterConfig (15-state layout) and the GNSS/baro
 * part of ins_hil.core.NavConfig; ins_ekf_default_cfg() gives the same defaults. */
typedef struct {
    ins_real gyro_arw;     /* gyro white noise, rad/s/sqrt(Hz) */
    ins_real accel_vrw;    /* accel white noise, m/s^2/sqrt(Hz) */
    ins_real gyro_bias_sigma, gyro_bias_tau;   /* Gauss-Markov bias: 1-sigma (rad/s), tau (s, > 0) */
    ins_real accel_bias_sigma, accel_bias_tau; /* same for the accelerometer (m/s^2, s) */
    ins_real p0_pos, p0_vel, p0_att, p0_yaw, p0_bg, p0_ba; /* initial 1-sigma (m, m/s, rad, rad, rad/s, m/s^2) */
    int second_order;      /* Phi = I + F dt + (F dt)^2 / 2 (book eq. 3.2) instead of I + F dt */
    ins_real gate_gnss, gate_baro; /* innovation gates in sigma (per component, test ratio > 1 rejects) */
    int gnss_reset_after;  /* after this many consecutive rejected GNSS positions: reset pos sigma and accept */
    ins_real gnss_min_std_ne, gnss_min_std_d, gnss_min_std_vel; /* floors on the reported GNSS sigmas */
    int use_gnss_vel;
    ins_real baro_std;     /* m */
    int have_baro_offset;  /* 1: baro_offset is given; 0: from the first sample, then calibrated against GNSS */
    double baro_offset;    /* ellipsoidal height of the baro altitude datum, m */
    double baro_offset_tau; /* time constant of that calibration, s (<= 0: off) */
    ins_real lever_arm[3];  /* IMU -> GNSS antenna, body FRD, m (NavConfig.gnss.lever_arm_b) */
    ins_real gnss_std_scale; /* factor on the floored GNSS sigmas (gnss.std_scale) */
    ins_real gyro_vib_gain, accel_vib_gain, vib_tau; /* vibration noise (FilterConfig.*_vib_gain, vib_tau s) */
    int cov_every;         /* propagate P every N steps with the averaged specific force (>= 1) */
    /* ground-vehicle aids (NavConfig.aids, without lever arm / mounting states) */
    int nhc, nhc_vertical, zupt, zaru;
    ins_real nhc_std, nhc_std_vertical, nhc_rate, nhc_min_speed;  /* m/s, m/s, Hz, m/s */
    ins_real zupt_std, zupt_gyro, zupt_accel, zupt_time, zupt_tau, zupt_max_speed, zaru_std;
    ins_real aids_gate;    /* innovation gate of the aids, sigma */
    ins_real g_local;      /* gravity of the rest detector, m/s^2 */
    /* magnetometer (NavConfig.mag; no hard-iron states): reference field NED (any unit), unit-vector sigma */
    int have_mag;
    ins_real mag_ref[3], mag_std, mag_gate;
    /* no-aid hold (NavConfig.hold): constant position / zero velocity while no GNSS position for hold_after s */
    int hold, have_hold_pos;
    double hold_lat, hold_lon, hold_h; /* where to hold before any GNSS position (rad, rad, m) */
    ins_real hold_after, hold_std, hold_vel_std, hold_rate, hold_gate;
    /* lost IMU data: the unknown motion of a gap (FilterConfig.gap_accel_sigma m/s^2, gap_rate_sigma rad/s) */
    ins_real gap_accel_sigma, gap_rate_sigma;
    /* scale-factor states (FilterConfig.scale_factors: 21 states): Gauss-Markov 1-sigma, tau (s), initial 1-sigma */
    int scale_factors;
    ins_real gyro_sf_sigma, accel_sf_sigma, sf_tau, p0_sg, p0_sa[3];
} ins_ekf_cfg_t;

enum {
    INS_GRP_GNSS_POS = 0,
    INS_GRP_GNSS_VEL = 1,
    INS_GRP_BARO = 2,
    INS_GRP_NHC = 3,
    INS_GRP_ZUPT = 4,
    INS_GRP_MAG = 5,
    INS_GRP_HOLD = 6,
    INS_NGRP = 7
};

typedef struct {
    ins_real P[INS_NX][INS_NX];
    ins_real x[INS_NX];
    ins_real bg[3], ba[3];  /* estimated gyro (rad/s) and accel (m/s^2) biases, body */
    ins_real qc[INS_NX];    /* continuous noise densities (diagonal) */
    ins_real inv_tau_g, inv_tau_a;
    int second_order;
    ins_real gate[INS_NGRP];
    int gnss_reset_after, use_gnss_vel;
    ins_real min_std[3];    /* GNSS NE, D, vel floors */
    ins_real baro_std;
    ins_pos baro_offset;    /* baro datum -> ellipsoid, m (configured, or first sample + GNSS calibration) */
    int have_baro_offset, baro_offset_fixed;
    double baro_offset_var, baro_offset_tau, t_baro;
    double t_gnss_ok;       /* time of the last accepted GNSS position (-1e300: none) */
    ins_pos h_gnss;         /* its height */
    double gnss_var_d;
    double baro_dt, gnss_dt; /* the last baro and GNSS-height intervals, s (for the datum's error in R) */
    uint32_t accepted[INS_NGRP], rejected[INS_NGRP], consecutive[INS_NGRP];
    ins_real last_ratio[INS_NGRP];
    uint32_t n_predict;
    ins_real lever[3], std_scale;
    /* vibration noise: gains, tau, previous compensated rate/force (body) and E[d^2] per axis */
    ins_real vib_gain[2], vib_tau, vib_prev[6], vib_var[6];
    int vib, have_vib_prev;
    /* cov_every accumulators */
    int cov_every, acc_n;
    ins_real acc_dt, acc_f[3], acc_q[2][3][3];
    /* ground aids: rest detector and NHC/ZUPT settings */
    int nhc, nhc_vertical, zupt, zaru;
    ins_real nhc_std, nhc_std_vertical, nhc_min_speed;
    double nhc_period; /* s, 1 / nhc_rate (double: the tick times stay those of the Python) */
    ins_real zupt_std, zupt_gyro, zupt_accel, zupt_time, zupt_tau, zupt_max_speed, zaru_std, g_local;
    double nhc_next, still_time;
    ins_real ema_w[3], ema_f[3];
    int replaying;         /* a delayed-fusion replay: gates apply, counters do not move */
    int gate_only;         /* an accepted group is counted, not applied (ins_hist_fuse_gnss_split; 0 otherwise) */
    int have_mag;
    ins_real mag_ref[3], mag_std;   /* unit reference field (NED) */
    int hold, have_hold_pos;
    double hold_pos[3], t_hold_gnss, t_hold;   /* live state (not rolled back, as NoAidHold) */
    ins_real hold_after, hold_std, hold_vel_std;
    double hold_period;
    ins_real gap_accel_sigma, gap_rate_sigma;
    int nx;                 /* active error states: 15, or 21 with the scale factors */
    ins_real sg[3], sa[3];  /* estimated gyro / accel scale factors (w~ = (1 + s) w + b) */
    ins_real inv_tau_s;     /* 1 / sf_tau */
    ins_real acc_w[3], acc_fb[3]; /* cov_every accumulators of the body rate and specific force (scale factors) */
} ins_ekf_t;

/* Default configuration: the defaults of ins_hil.fusion.ekf.FilterConfig / ins_hil.core.NavConfig. */
void ins_ekf_default_cfg(ins_ekf_cfg_t *cfg);
void ins_ekf_init(ins_ekf_t *e, const ins_ekf_cfg_t *cfg);
/* Covariance predict over one step after ins_mech_step(): P = Phi P Phi^T + Q dt, with F from the
 * mechanization's last f_ned, Earth/transport rates and attitude (see ekf.c). */
void ins_ekf_predict(ins_ekf_t *e, const ins_mech_t *m);
/* Predict with the vibration noise (w_b, f_b: this step's compensated body rate rad/s and specific force
 * m/s^2) and the cov_every accumulation, as ErrorStateEKF.predict. */
void ins_ekf_predict_full(ins_ekf_t *e, const ins_mech_t *m, const ins_real w_b[3], const ins_real f_b[3]);
/* Predict across gap s of lost IMU data after a coasting mechanization step (c9: C_b^n before it). */
void ins_ekf_predict_gap(ins_ekf_t *e, const ins_mech_t *m, const ins_real c9[9], ins_real gap);
/* Joseph-form scalar update for the residual z (measured - predicted, before x), row h, noise variance r. */
void ins_ekf_update_scalar(ins_ekf_t *e, const ins_real h[INS_NX], ins_real z, ins_real r);
/* Symmetrise P (after a group of scalar updates). */
void ins_ekf_symmetrize(ins_ekf_t *e);
/* Fold the error state into the navigation state and the biases, reset x. */
void ins_ekf_feedback(ins_ekf_t *e, ins_mech_t *m);

/* --------------------------------------------------------------- core (all) */

typedef struct {
    double t;
    ins_pos lat, lon, h;
    ins_real vel[3];      /* NED m/s, or NaN components for "no velocity" */
    ins_real std_ne, std_d, std_vel;
} ins_gnss_t;

typedef struct {
    ins_mech_t mech;
    ins_ekf_t ekf;
    int filter;           /* 0: mechanization only; 1: + EKF predict each step */
    uint32_t steps;
    /* if not NULL (caller-owned, set after ins_core_init): each step writes here the state after its
     * mechanization, before the filter time update, the ground aids and the hold (the state a real-time loop
     * publishes at once: NavCore.step_begin; sigma of the previous step). Not written during a roll-back replay. */
    struct ins_out_s *pub;
} ins_core_t;

/* Flat output record of one state (for logs and the Python wrapper). */
typedef struct ins_out_s {
    double t;
    ins_real q[4], v[3];
    ins_pos lat, lon, h;
    ins_real bg[3], ba[3];
    ins_real std_pos[3], std_vel[3], std_att[3];
} ins_out_t;

void ins_core_init(ins_core_t *c, const ins_real q[4], const ins_real v[3], ins_pos lat, ins_pos lon, ins_pos h,
                   double t, ins_real dt, const ins_ekf_cfg_t *cfg, int filter);
/* One IMU step: bias-correct the increments, mechanize, EKF predict (if filter). t_end: sensor time. */
void ins_core_step(ins_core_t *c, const ins_real dth[3], const ins_real dv[3], double t_end);
/* One IMU step of its own length dt (s; a log's jittering sample periods): as ins_core_step with the step period
 * set to dt. A sample whose interval starts more than dt/2 after the last state (lost IMU data) is preceded by a
 * coasting step at constant velocity and attitude over the gap (at most 10 s) and the gap's covariance growth. */
void ins_core_step_dt(ins_core_t *c, const ins_real dth[3], const ins_real dv[3], double t_end, ins_real dt);
/* n IMU steps in one call: inc is n x 6 (dtheta, dvel), t_end is n times (or NULL: t += dt);
 * out (n records, or NULL). */
void ins_core_run(ins_core_t *c, const ins_real *inc, const double *t_end, size_t n, ins_out_t *out);
/* GNSS fix: position group, feedback, then (if all vel components are finite) velocity group,
 * feedback; each group gated (per-component test ratio), then sequential scalar Joseph updates.
 * The position is shifted by v (t_now - g->t) to the current step. Returns a bit mask of the
 * accepted groups (1 position, 2 velocity). */
int ins_core_fuse_gnss(ins_core_t *c, const ins_gnss_t *g);
/* GNSS positions rejected gnss_reset_after times in a row re-initialise the position and velocity sigma
 * and are then accepted. A fix older than 1.5 steps is taken as valid now (no shift). */
/* Baro altitude valid at t (m above its datum: the datum is configured, or the first sample's, then
 * calibrated against accepted GNSS heights with time constant baro_offset_tau; its variance is added to R).
 * Returns 1 if accepted. */
int ins_core_fuse_baro(ins_core_t *c, double t, ins_pos altitude);
/* Magnetometer field (body FRD, any unit) valid now: the book's two-component update (eqs. 3.28-3.38) against
 * the configured reference. Returns 1 if accepted (0 also when no reference is configured). */
int ins_core_fuse_mag(ins_core_t *c, double t, const ins_real field_b[3]);
/* ins_core_fuse_gnss with the time alignment chosen by the caller (assume_now: no v dt shift). */
int ins_core_fuse_gnss_at(ins_core_t *c, const ins_gnss_t *g, int assume_now);
void ins_core_output(const ins_core_t *c, ins_out_t *o);

/* ------------------------------------------------------ delayed fusion (roll-back) */

/* Delayed fusion as ins_hil.core_parts.history.DelayedHistory: a snapshot of the core after every step
 * (the last max_delay + 2 dt s of them), the IMU increments and the fused measurements since the oldest.
 * A measurement older than half a step is fused at the snapshot nearest its time, and the logged IMU
 * steps and measurements are replayed up to now (gated, not counted). Fixed capacity: INS_HIST_N steps
 * (max_delay / dt + 3 must fit: 1.9 s at 200 Hz, 0.38 s at 1 kHz; 2.1 MB in double, 1.1 MB in float (21 states):
 * allocate it statically or with the caller's allocator) and INS_HIST_MEAS measurements; a measurement older
 * than the history is fused now, as NavCore does beyond its history. */
#ifndef INS_HIST_N
#define INS_HIST_N 384
#endif
#define INS_HIST_MEAS 256
typedef struct {
    uint32_t step;      /* the step it was fused at (NavCore's log label) */
    int kind;           /* 0 GNSS, 1 baro, 2 magnetometer */
    ins_gnss_t g;       /* GNSS (NaN lat: velocity only; NaN vel: position only) */
    ins_real field[3];  /* magnetometer */
    double t;           /* baro: time, altitude */
    ins_pos alt;
} ins_hmeas_t;
typedef struct {
    ins_core_t snap[INS_HIST_N];
    uint32_t snap_step[INS_HIST_N];
    double snap_t[INS_HIST_N];
    uint32_t snap_first, snap_n;       /* ring: oldest index, count */
    uint32_t snap_cap;                 /* ring slots in use (doubled when full, up to INS_HIST_N) */
    ins_real imu[INS_HIST_N][7];       /* increments and dt of step k at k % INS_HIST_N */
    double imu_t[INS_HIST_N];
    ins_hmeas_t meas[INS_HIST_MEAS];
    uint32_t meas_first, meas_n;
    double max_delay;
    uint32_t rollbacks, too_old;       /* roll-backs done; measurements older than the history */
} ins_hist_t;

void ins_hist_init(ins_hist_t *h, double max_delay);
/* One IMU step through the history (log, ins_core_step, snapshot). */
void ins_hist_step(ins_hist_t *h, ins_core_t *c, const ins_real dth[3], const ins_real dv[3], double t_end,
                   ins_real dt);
/* A GNSS fix / baro altitude valid at its time: rolled back if older than half a step. */
int ins_hist_fuse_gnss(ins_hist_t *h, ins_core_t *c, const ins_gnss_t *g);
int ins_hist_fuse_baro(ins_hist_t *h, ins_core_t *c, double t, ins_pos altitude);
/* A GNSS fix whose velocity (gnss.vel_delay) is valid at vel->t, before its position's pos->t (pos: the position
 * alone, vel: the velocity alone): ins_hist_fuse_gnss(pos), then ins_hist_fuse_gnss(vel), no IMU step between; the
 * same numbers, with one position update less when the velocity rolls the history back (the position is then only
 * gated and counted: the roll-back's replay fuses it at its step). after_pos (may be NULL) is called with ctx between
 * the two (a caller reading the position's gate). *r_pos: the position's result; returns the velocity's. */
int ins_hist_fuse_gnss_split(ins_hist_t *h, ins_core_t *c, const ins_gnss_t *pos, const ins_gnss_t *vel, int *r_pos,
                             void (*after_pos)(void *ctx, const ins_core_t *c), void *ctx);
int ins_hist_fuse_mag(ins_hist_t *h, ins_core_t *c, double t, const ins_real field_b[3]);

/* ---------------------------------------------------------------------- FDI */

/* Parity-space FDI for n redundant single-axis gyros y = A w + e (DIGEST_000
 * section 5.1-5.2): p = U2^T y, J(k) = |p|^2 - (u_k.p)^2/|u_k|^2 (eq. 5.17
 * corrected), isolated sensor argmin J, fault size rho = u_k.p/|u_k|^2 (5.16).
 * U2^T is computed offline from the geometry A (tools/gen_parity.py). */
#define INS_FDI_N 5
#define INS_FDI_M 2
typedef struct {
    ins_real p[INS_FDI_M];     /* parity vector */
    ins_real p2;               /* |p|^2 (detection statistic) */
    ins_real J[INS_FDI_N];     /* isolation cost per candidate */
    ins_real rho[INS_FDI_N];   /* fault size per candidate */
    int detected;              /* p2 > threshold */
    int isolated;              /* argmin J (0-based), -1 if not detected */
} ins_fdi_result_t;

/* The offline projector of the book's 5-gyro cone (Example 5.1): U2^T, 2 x 5. */
void ins_fdi_cone5_u2t(ins_real u2t[INS_FDI_M * INS_FDI_N]);
void ins_fdi_parity(const ins_real u2t[INS_FDI_M * INS_FDI_N], const ins_real y[INS_FDI_N], ins_real threshold,
                    ins_fdi_result_t *r);

/* ------------------------------------------------------- GNSS-velocity yaw bank */

/* The EKF-GSF yaw estimator (PX4 EKF2 EKFGSF_yaw; ins_hil.fusion.yaw_gsf.YawGsf, whose numbers the double
 * build reproduces to round-off): n yaw hypotheses, each an attitude reference (gyro + accelerometer tilt
 * correction, its own gyro bias) and a 3-state EKF [v_N, v_E, psi] corrected by the GNSS velocity; the composite
 * yaw is the weighted circular mean. The alignment phase of a log without magnetometer (alignment.yaw_gsf). */
#define INS_GSF_N 8 /* hypotheses at most */
typedef struct {
    int n;                                   /* hypotheses (2..INS_GSF_N) */
    ins_real tilt_gain, gyro_bias_gain, gyro_bias_max, bias_spin_max, gyro_noise, accel_noise, vel_std_min;
    int tilt_aligned, started;               /* tilt set from a 1-g specific force; velocity fusion started */
    ins_real R[INS_GSF_N][9];                /* C_b^n of each model (row-major) */
    ins_real bias[INS_GSF_N][3];             /* each model's gyro bias (rad/s, body) */
    ins_real X[INS_GSF_N][3];                /* [v_N, v_E, psi] (m/s, m/s, rad) */
    ins_real P[INS_GSF_N][9];                /* its covariance (row-major 3x3) */
    ins_real W[INS_GSF_N];                   /* model weights (sum 1) */
    ins_real accel[3];                       /* low-passed specific force (m/s^2, body) */
    ins_real yaw, yaw_var;                   /* composite yaw (rad) and its variance (rad^2; infinite: none yet) */
    uint32_t updates;                        /* GNSS velocities fused */
} ins_gsf_t;

/* PX4's defaults (GsfConfig) for n models. */
void ins_gsf_init(ins_gsf_t *g, int n);
/* One IMU interval: dtheta (rad), dvel (m/s) body FRD over dt s; forward_speed (m/s along body x, 0 = unknown). */
void ins_gsf_predict(ins_gsf_t *g, const ins_real dtheta[3], const ins_real dvel[3], ins_real dt,
                     ins_real forward_speed);
/* A GNSS horizontal velocity (m/s, NE) with its sigma (m/s). */
void ins_gsf_fuse_vel(ins_gsf_t *g, const ins_real vel_ne[2], ins_real std);

/* ------------------------------------------------------- static alignment (align.c) */

/* The levelling window of the static alignment (ins_hil.core_parts.alignment.Alignment.step in phase "level"):
 * the samples of the last `time` s at rest (the window: their sums) and those of the last `still_delay` s not yet
 * in it (held back, so that a motion the GNSS speed shows late stays out of the window; `frozen` s once the IMU's
 * motion test has fired), in one ring of INS_LEVEL_N samples; the IMU's motion test (the smoothed squared departure
 * of the rate and the specific force from the window's mean, time constant still_tau). Fixed capacity: a sample the
 * ring cannot take is refused (INS_LEVEL_FULL, nothing changed) and the caller levels on without the ring. */
#ifndef INS_LEVEL_N
#define INS_LEVEL_N 8192 /* samples (window + held back): 41 s at 200 Hz, 8.2 s at 1 kHz; 512 KB in double */
#endif
#define INS_LEVEL_DUE 1  /* the levelling is due after this sample (Alignment._level) */
#define INS_LEVEL_FULL 2 /* the ring is full: the sample was not taken */
typedef struct {
    double time, still_delay, frozen, still_tau; /* s (AlignmentConfig; frozen: alignment.MAX_FROZEN_S) */
    double gyro2, accel2;           /* the motion test's thresholds squared ((rad/s)^2, (m/s^2)^2) */
    double t[INS_LEVEL_N], dt[INS_LEVEL_N];        /* each sample's end time and interval (s) */
    ins_real dth[INS_LEVEL_N][3], dv[INS_LEVEL_N][3]; /* its increments (rad, m/s, body FRD) */
    uint32_t first, n_win, n_pend;  /* ring: the oldest sample; the window's count, then the held-back ones */
    ins_real f_sum[3], w_sum[3];    /* sums of dvel and dtheta over the window (m/s, rad, body) */
    double t_win;                   /* the window's length (s) */
    double dev_w, dev_f;            /* the smoothed squared departures ((rad/s)^2, (m/s^2)^2) */
    int moving, imu_moving;         /* motion seen (a GNSS speed, set by the caller, or the IMU); the IMU's test fired */
    int have_pos, yaw_ready;        /* set by the caller: a position is known; a yaw needs no motion (mag, level_only,
                                       gyrocompass) */
} ins_level_t;

void ins_level_init(ins_level_t *l, double time, double still_delay, double frozen, double still_tau, double gyro2,
                    double accel2);
/* One IMU interval (dtheta rad, dvel m/s body FRD over dt s, ending at t s) into the window; returns
 * INS_LEVEL_DUE when the levelling is due (a position, the window full or moving, a yaw source), INS_LEVEL_FULL
 * (not taken), else 0. */
int ins_level_step(ins_level_t *l, const ins_real dtheta[3], const ins_real dvel[3], double dt, double t);

/* The start-up check's sums (ins_hil.core_parts.sensor_check.SensorCheck.add): the specific force and rate and
 * their squares over the first `window` s; the judging is the caller's. */
typedef struct {
    double window, t;               /* s: the check's length, the time summed */
    uint32_t n;                     /* samples summed */
    ins_real sf[3], sf2[3], sw[3], sw2[3]; /* sums of f (m/s^2), f^2, w (rad/s), w^2 (body) */
} ins_imu_check_t;

void ins_imu_check_init(ins_imu_check_t *c, double window);
/* One interval (dt <= 0: ignored); returns 1 when the window is full (judge now), else 0. */
int ins_imu_check_add(ins_imu_check_t *c, const ins_real dtheta[3], const ins_real dvel[3], double dt);

/* One IMU interval of the alignment's heading phase (levelled, waiting for the yaw; NavCore's Alignment.step):
 * the increments bias-compensated (bg rad/s, ba m/s^2), the yaw bank g (or NULL) fed with the compensated
 * dtheta and the raw dvel, then the strapdown step over dt with the velocity held at zero afterwards; the time
 * set to t_end; omega_b: the compensated rate (rad/s). */
void ins_align_heading_step(ins_mech_t *m, ins_gsf_t *g, const ins_real dtheta[3], const ins_real dvel[3], ins_real dt,
                            double t_end, const ins_real bg[3], const ins_real ba[3], ins_real omega_b[3]);

/* ------------------------------------------------------------ serial frame */

/* ins_hil serial IMU frame v1 (drivers/SERIAL_FRAME.md), 41 bytes little endian. */
#define INS_FRAME_LEN 41
typedef struct {
    uint8_t imu_id, flags;
    uint16_t seq, dt_us;
    uint32_t t_us;
    float dtheta[3], dvel[3];
    int16_t temp_cdeg;
} ins_frame_t;

uint16_t ins_crc16_ccitt(const uint8_t *data, size_t n, uint16_t init);
/* Decode one frame at buf (>= 41 bytes); 0 ok, -1 sync, -2 version, -3 crc. */
int ins_frame_decode(const uint8_t *buf, ins_frame_t *f);

#ifdef __cplusplus
}
#endif
#endif /* INS_REF_H */
