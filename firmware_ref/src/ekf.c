/* 15-state error-state EKF: predict every IMU step, Joseph-form sequential
 * scalar updates, feedback and reset.
 *
 * Mirrors ins_hil.fusion.ekf.ErrorStateEKF (15-state layout, Joseph numerics,
 * cov_every = 1) and the feedback of ins_hil.core.NavCore, which follow
 * DIGEST_000 section 9 (dr, dv = true - computed, C_hat = (I + [psi x]) C,
 * bias errors = true - estimated) and the NED form of seed 001 eqs. 83-101
 * (DIGEST_001_004 section 1.9):
 *   d(dr)/dt  = dv
 *   d(dv)/dt  = [f_n x] psi - (2 w_ie + w_en) x dv - C_b^n dba + (0, 0, 2 g/R dr_D)
 *   d(psi)/dt = -w_in x psi + C_b^n dbg           (book eq. 3.40, seed 001 eq. 98)
 *   d(db)/dt  = -db / tau + w                      (seed 001 eqs. 87/88)
 * Phi = I + F dt + (F dt)^2 / 2 (book eq. 3.2), P = Phi P Phi^T + Q dt (book
 * eq. 3.19) with diagonal Q: VRW^2, ARW^2, 2 sigma_b^2 / tau.
 * Phi is never formed: Phi M = M + dt (F M) + dt^2/2 F (F M) with F applied by
 * its block sparsity (f_mul), so a predict costs ~4 sparse products.
 */
#include "ins_internal.h"
#include "generated/ins_jacobians.h"

enum { IR = 0, IV = 3, IA = 6, IG = 9, IB = 12, ISG = 15, ISA = 18 };

void ins_ekf_default_cfg(ins_ekf_cfg_t *cfg) {
    /* = ins_hil.fusion.ekf.FilterConfig() and ins_hil.core.NavConfig() */
    const double deg = 3.14159265358979323846 / 180.0;
    cfg->gyro_arw = K(0.15 * deg / 60.0);
    cfg->accel_vrw = K(70e-6 * 9.80665);
    cfg->gyro_bias_sigma = K(20.0 * deg / 3600.0);
    cfg->gyro_bias_tau = K(300.0);
    cfg->accel_bias_sigma = K(0.5e-3 * 9.80665);
    cfg->accel_bias_tau = K(300.0);
    cfg->p0_pos = K(5.0);
    cfg->p0_vel = K(1.0);
    cfg->p0_att = K(2.0 * deg);
    cfg->p0_yaw = K(10.0 * deg);
    cfg->p0_bg = K(0.3 * deg);
    cfg->p0_ba = K(0.3);
    cfg->second_order = 1;
    cfg->gate_gnss = K(5.0);
    cfg->gate_baro = K(5.0);
    cfg->gnss_reset_after = 10;
    cfg->gnss_min_std_ne = K(0.01);
    cfg->gnss_min_std_d = K(0.01);
    cfg->gnss_min_std_vel = K(0.02);
    cfg->use_gnss_vel = 1;
    cfg->baro_std = K(0.5);
    cfg->have_baro_offset = 0;
    cfg->baro_offset = 0.0;
    cfg->baro_offset_tau = 10.0;
    cfg->lever_arm[0] = cfg->lever_arm[1] = cfg->lever_arm[2] = K(0.0);
    cfg->gnss_std_scale = K(1.0);
    cfg->gyro_vib_gain = cfg->accel_vib_gain = K(0.0);
    cfg->vib_tau = K(1.0);
    cfg->cov_every = 1;
    /* = ins_hil.core_parts.config.AidsConfig() */
    cfg->nhc = cfg->zupt = 0;
    cfg->nhc_vertical = cfg->zaru = 1;
    cfg->nhc_std = K(0.1);
    cfg->nhc_std_vertical = K(0.1);
    cfg->nhc_rate = K(10.0);
    cfg->nhc_min_speed = K(0.5);
    cfg->zupt_std = K(0.02);
    cfg->zupt_gyro = K(0.02);
    cfg->zupt_accel = K(0.15);
    cfg->zupt_time = K(0.5);
    cfg->zupt_tau = K(0.3);
    cfg->zupt_max_speed = K(1.0);
    cfg->zaru_std = K(0.002);
    cfg->aids_gate = K(5.0);
    cfg->g_local = K(9.80665);
    cfg->have_mag = 0; /* = MagConfig() */
    cfg->mag_ref[0] = cfg->mag_ref[1] = cfg->mag_ref[2] = K(0.0);
    cfg->mag_std = K(0.0524);
    cfg->mag_gate = K(5.0);
    cfg->hold = cfg->have_hold_pos = 0; /* = HoldConfig() */
    cfg->hold_lat = cfg->hold_lon = cfg->hold_h = 0.0;
    cfg->hold_after = K(5.0);
    cfg->hold_std = K(10.0);
    cfg->hold_vel_std = K(1.0);
    cfg->hold_rate = K(5.0);
    cfg->hold_gate = K(5.0);
    cfg->gap_accel_sigma = K(1.0);
    cfg->gap_rate_sigma = K(3.0 * deg);
    cfg->scale_factors = 0; /* = FilterConfig(): gyro_sf_sigma, accel_sf_sigma, sf_tau, init_sf */
    cfg->gyro_sf_sigma = K(1e-3);
    cfg->accel_sf_sigma = K(2e-3);
    cfg->sf_tau = K(3600.0);
    cfg->p0_sg = K(2e-3);
    cfg->p0_sa[0] = cfg->p0_sa[1] = cfg->p0_sa[2] = K(2e-3);
}

void ins_ekf_init(ins_ekf_t *e, const ins_ekf_cfg_t *cfg) {
    int i, j;
    const ins_real sig[INS_NX] = {cfg->p0_pos, cfg->p0_pos, cfg->p0_pos, cfg->p0_vel, cfg->p0_vel,
                                  cfg->p0_vel, cfg->p0_att, cfg->p0_att, cfg->p0_yaw, cfg->p0_bg,
                                  cfg->p0_bg,  cfg->p0_bg,  cfg->p0_ba,  cfg->p0_ba,  cfg->p0_ba};
    e->nx = cfg->scale_factors ? 21 : 15;
    for (i = 0; i < INS_NX; ++i) {
        for (j = 0; j < INS_NX; ++j) e->P[i][j] = K(0.0);
        e->P[i][i] = i < 15 ? sig[i] * sig[i] : K(0.0);
        e->x[i] = K(0.0);
        e->qc[i] = K(0.0);
    }
    e->inv_tau_s = K(0.0);
    for (i = 0; i < 3; ++i) {
        e->sg[i] = e->sa[i] = e->acc_w[i] = e->acc_fb[i] = K(0.0);
        if (e->nx == 21) { /* ErrorStateEKF: init_sf / init_accel_sf, 2 sigma^2 / tau */
            e->P[ISG + i][ISG + i] = cfg->p0_sg * cfg->p0_sg;
            e->P[ISA + i][ISA + i] = cfg->p0_sa[i] * cfg->p0_sa[i];
            e->qc[ISG + i] = K(2.0) * cfg->gyro_sf_sigma * cfg->gyro_sf_sigma / cfg->sf_tau;
            e->qc[ISA + i] = K(2.0) * cfg->accel_sf_sigma * cfg->accel_sf_sigma / cfg->sf_tau;
            e->inv_tau_s = K(1.0) / cfg->sf_tau;
        }
    }
    for (i = 0; i < 3; ++i) {
        e->bg[i] = e->ba[i] = K(0.0);
        e->qc[IR + i] = K(0.0);
        e->qc[IV + i] = cfg->accel_vrw * cfg->accel_vrw;
        e->qc[IA + i] = cfg->gyro_arw * cfg->gyro_arw;
        e->qc[IG + i] = K(2.0) * cfg->gyro_bias_sigma * cfg->gyro_bias_sigma / cfg->gyro_bias_tau;
        e->qc[IB + i] = K(2.0) * cfg->accel_bias_sigma * cfg->accel_bias_sigma / cfg->accel_bias_tau;
    }
    e->inv_tau_g = K(1.0) / cfg->gyro_bias_tau;
    e->inv_tau_a = K(1.0) / cfg->accel_bias_tau;
    e->second_order = cfg->second_order;
    e->gate[INS_GRP_GNSS_POS] = e->gate[INS_GRP_GNSS_VEL] = cfg->gate_gnss;
    e->gate[INS_GRP_BARO] = cfg->gate_baro;
    e->gnss_reset_after = cfg->gnss_reset_after;
    e->use_gnss_vel = cfg->use_gnss_vel;
    e->min_std[0] = cfg->gnss_min_std_ne;
    e->min_std[1] = cfg->gnss_min_std_d;
    e->min_std[2] = cfg->gnss_min_std_vel;
    e->baro_std = cfg->baro_std;
    e->baro_offset = cfg->baro_offset;
    e->have_baro_offset = 0;
    e->baro_offset_fixed = cfg->have_baro_offset;
    e->baro_offset_var = 0.0;
    e->baro_offset_tau = cfg->baro_offset_tau;
    e->t_baro = 0.0;
    e->t_gnss_ok = -1e300;
    e->h_gnss = 0.0;
    e->gnss_var_d = 1.0;
    e->baro_dt = 0.04;
    e->gnss_dt = 1.0;
    for (i = 0; i < INS_NGRP; ++i) {
        e->accepted[i] = e->rejected[i] = e->consecutive[i] = 0;
        e->last_ratio[i] = K(0.0);
    }
    e->n_predict = 0;
    for (i = 0; i < 3; ++i) e->lever[i] = cfg->lever_arm[i];
    e->std_scale = cfg->gnss_std_scale;
    e->vib_gain[0] = cfg->gyro_vib_gain;
    e->vib_gain[1] = cfg->accel_vib_gain;
    e->vib_tau = cfg->vib_tau;
    e->vib = cfg->gyro_vib_gain > K(0.0) || cfg->accel_vib_gain > K(0.0);
    e->have_vib_prev = 0;
    for (i = 0; i < 6; ++i) e->vib_prev[i] = e->vib_var[i] = K(0.0);
    e->cov_every = cfg->cov_every < 1 ? 1 : cfg->cov_every;
    e->acc_n = 0;
    e->acc_dt = K(0.0);
    for (i = 0; i < 3; ++i) {
        e->acc_f[i] = K(0.0);
        for (j = 0; j < 3; ++j) e->acc_q[0][i][j] = e->acc_q[1][i][j] = K(0.0);
    }
    e->gate[INS_GRP_NHC] = e->gate[INS_GRP_ZUPT] = cfg->aids_gate;
    e->nhc = cfg->nhc;
    e->nhc_vertical = cfg->nhc_vertical;
    e->zupt = cfg->zupt;
    e->zaru = cfg->zaru;
    e->nhc_std = cfg->nhc_std;
    e->nhc_std_vertical = cfg->nhc_std_vertical;
    e->nhc_period = 1.0 / (double)cfg->nhc_rate;
    e->nhc_min_speed = cfg->nhc_min_speed;
    e->zupt_std = cfg->zupt_std;
    e->zupt_gyro = cfg->zupt_gyro;
    e->zupt_accel = cfg->zupt_accel;
    e->zupt_time = cfg->zupt_time;
    e->zupt_tau = cfg->zupt_tau;
    e->zupt_max_speed = cfg->zupt_max_speed;
    e->zaru_std = cfg->zaru_std;
    e->g_local = cfg->g_local;
    e->nhc_next = 0.0;
    e->still_time = 0.0;
    for (i = 0; i < 3; ++i) e->ema_w[i] = K(0.0);
    e->ema_f[0] = e->ema_f[1] = K(0.0);
    e->ema_f[2] = K(-9.80665);
    e->replaying = 0;
    e->have_mag = cfg->have_mag;
    e->mag_std = cfg->mag_std;
    e->gate[INS_GRP_MAG] = cfg->mag_gate;
    {
        const ins_real n = RS(cfg->mag_ref[0] * cfg->mag_ref[0] + cfg->mag_ref[1] * cfg->mag_ref[1] +
                              cfg->mag_ref[2] * cfg->mag_ref[2]);
        for (i = 0; i < 3; ++i) e->mag_ref[i] = n > K(0.0) ? cfg->mag_ref[i] / n : K(0.0);
        if (!(n > K(0.0))) e->have_mag = 0;
    }
    e->hold = cfg->hold;
    e->have_hold_pos = cfg->have_hold_pos;
    e->hold_pos[0] = cfg->hold_lat;
    e->hold_pos[1] = cfg->hold_lon;
    e->hold_pos[2] = cfg->hold_h;
    e->t_hold_gnss = e->t_hold = -1e300;
    e->hold_after = cfg->hold_after;
    e->hold_std = cfg->hold_std;
    e->hold_vel_std = cfg->hold_vel_std;
    e->hold_period = 1.0 / (double)cfg->hold_rate;
    e->gap_accel_sigma = cfg->gap_accel_sigma;
    e->gap_rate_sigma = cfg->gap_rate_sigma;
    e->gate[INS_GRP_HOLD] = cfg->hold_gate;
}

/* F: the generated blocks (generated/ins_jacobians.h, from tools/derive_jacobians.py) and the bias rows */
typedef struct {
    ins_real itg, ita, its;
    ins_gen_fblocks_t b;
    int nx;
    ins_gen_fsf_t s; /* the scale-factor columns (generated: F[6:9][15:18], F[3:6][18:21]) */
} fmat_t;

/* out = F in (F block-sparse: the structure derive_jacobians.py checks) */
static void f_mul(const fmat_t *f, ins_real in[INS_NX][INS_NX], ins_real out[INS_NX][INS_NX]) {
    const ins_gen_fblocks_t *b = &f->b;
    const int n = f->nx;
    int i, j, k;
    for (j = 0; j < n; ++j) {
        for (i = 0; i < 3; ++i) {
            ins_real sv = K(0.0), sa = K(0.0);
            for (k = 0; k < 3; ++k) {
                sv += b->vv[i][k] * in[IV + k][j] + b->va[i][k] * in[IA + k][j] + b->vba[i][k] * in[IB + k][j];
                sa += b->aa[i][k] * in[IA + k][j] + b->abg[i][k] * in[IG + k][j];
            }
            if (i == 2) sv += b->vr_dd * in[IR + 2][j];
            out[IR + i][j] = in[IV + i][j];
            out[IV + i][j] = sv;
            out[IA + i][j] = sa;
            out[IG + i][j] = -f->itg * in[IG + i][j];
            out[IB + i][j] = -f->ita * in[IB + i][j];
        }
        if (n == 21)
            for (i = 0; i < 3; ++i) {
                ins_real sv = K(0.0), sa = K(0.0);
                for (k = 0; k < 3; ++k) {
                    sv += f->s.vsa[i][k] * in[ISA + k][j];
                    sa += f->s.asg[i][k] * in[ISG + k][j];
                }
                out[IV + i][j] += sv;
                out[IA + i][j] += sa;
                out[ISG + i][j] = -f->its * in[ISG + i][j];
                out[ISA + i][j] = -f->its * in[ISA + i][j];
            }
    }
}

/* out = Phi in = in + dt F in (+ dt^2/2 F F in); tmp, tmp2 scratch */
static void phi_mul(const fmat_t *f, ins_real dt, int second, ins_real in[INS_NX][INS_NX],
                    ins_real out[INS_NX][INS_NX], ins_real tmp[INS_NX][INS_NX], ins_real tmp2[INS_NX][INS_NX]) {
    const ins_real h2 = K(0.5) * dt * dt;
    const int n = f->nx;
    int i, j;
    f_mul(f, in, tmp);
    if (second) {
        f_mul(f, tmp, tmp2);
        for (i = 0; i < n; ++i)
            for (j = 0; j < n; ++j) out[i][j] = in[i][j] + dt * tmp[i][j] + h2 * tmp2[i][j];
    } else {
        for (i = 0; i < n; ++i)
            for (j = 0; j < n; ++j) out[i][j] = in[i][j] + dt * tmp[i][j];
    }
}

/* The vibration noise of one step (FilterConfig.gyro_vib_gain / accel_vib_gain, ErrorStateEKF._vibration_noise):
 * updates E[dw^2], E[df^2] (body) with this step's changes and returns q[0] = C diag((g_w dt)^2 E[dw^2]) C^T,
 * q[1] = C diag((g_f dt)^2 E[df^2]) C^T (NED; rad^2, (m/s)^2). */
static void vibration_noise(ins_ekf_t *e, ins_real dt, const ins_real c[9], const ins_real w_b[3],
                            const ins_real f_b[3], ins_real q[2][3][3]) {
    ins_real x[6], g[2], d[2][3];
    int i, j, k, b;
    for (i = 0; i < 3; ++i) {
        x[i] = w_b[i];
        x[3 + i] = f_b[i];
    }
    if (e->have_vib_prev) {
        ins_real a = dt / e->vib_tau;
        if (a > K(1.0)) a = K(1.0);
        for (i = 0; i < 6; ++i) {
            const ins_real dd = x[i] - e->vib_prev[i];
            e->vib_var[i] = e->vib_var[i] + a * (dd * dd - e->vib_var[i]);
        }
    }
    for (i = 0; i < 6; ++i) e->vib_prev[i] = x[i];
    e->have_vib_prev = 1;
    for (b = 0; b < 2; ++b) {
        g[b] = e->vib_gain[b] * dt;
        g[b] = g[b] * g[b];
        for (k = 0; k < 3; ++k) d[b][k] = g[b] * e->vib_var[3 * b + k];
        for (i = 0; i < 3; ++i)
            for (j = 0; j < 3; ++j) {
                ins_real acc = K(0.0);
                for (k = 0; k < 3; ++k) acc += c[3 * i + k] * d[b][k] * c[3 * j + k];
                q[b][i][j] = acc;
            }
    }
}

void ins_ekf_predict(ins_ekf_t *e, const ins_mech_t *m) { ins_ekf_predict_full(e, m, NULL, NULL); }

/* P = Phi P Phi^T + diag(qd) (+ the vibration blocks qv), F at the mechanization's state with the specific force fn
 * (NED) and, for the scale-factor columns, the body rate wb and specific force fb */
static void propagate(ins_ekf_t *e, const ins_mech_t *m, const ins_real c9[9], const ins_real fn[3], ins_real dt,
                      const ins_real qd[INS_NX], ins_real qv[2][3][3], const ins_real wb[3], const ins_real fb[3]) {
    fmat_t f;
    ins_real a[INS_NX][INS_NX], b[INS_NX][INS_NX], t1[INS_NX][INS_NX], t2[INS_NX][INS_NX];
    const int n = e->nx;
    int i, j;
    f.itg = e->inv_tau_g;
    f.ita = e->inv_tau_a;
    f.its = e->inv_tau_s;
    f.nx = n;
    if (n == 21) ins_gen_F_sf(c9, fb, wb, &f.s);
    /* d g / d(down) = +2 g / R (seed 001 eq. 96, corrected sign; DIGEST_001_004 section 1.9) */
    ins_gen_F_blocks(c9, fn, m->omega_ie, m->omega_en, K(2.0 * 9.80665 / 6371000.0), &f.b);
    phi_mul(&f, dt, e->second_order, e->P, a, t1, t2); /* A = Phi P */
    for (i = 0; i < n; ++i)
        for (j = 0; j < n; ++j) b[i][j] = a[j][i];
    phi_mul(&f, dt, e->second_order, b, a, t1, t2); /* Phi (Phi P)^T = Phi P Phi^T */
    for (i = 0; i < n; ++i) {
        for (j = 0; j < i; ++j) e->P[i][j] = e->P[j][i] = K(0.5) * (a[i][j] + a[j][i]);
        e->P[i][i] = a[i][i] + qd[i];
    }
    if (qv != NULL)
        for (i = 0; i < 3; ++i)
            for (j = 0; j < 3; ++j) {
                e->P[IA + i][IA + j] += qv[0][i][j];
                e->P[IV + i][IV + j] += qv[1][i][j];
            }
    e->n_predict++;
}

void ins_ekf_predict_full(ins_ekf_t *e, const ins_mech_t *m, const ins_real w_b[3], const ins_real f_b[3]) {
    ins_real c9[9], qv[2][3][3], fn[3], qd[INS_NX], wb[3] = {0, 0, 0}, fb[3] = {0, 0, 0};
    ins_real dt = m->dt;
    const int vib = e->vib && w_b != NULL && f_b != NULL;
    int i, j, k;
    ins_dcm_from_quat(m->q, c9);
    if (vib) vibration_noise(e, dt, c9, w_b, f_b, qv);
    for (i = 0; i < 3; ++i) fn[i] = m->f_ned[i];
    if (w_b != NULL && f_b != NULL)
        for (i = 0; i < 3; ++i) {
            wb[i] = w_b[i];
            fb[i] = f_b[i];
        }
    if (e->cov_every > 1) { /* accumulate; propagate every cov_every steps with the averaged f (ErrorStateEKF) */
        if (vib)
            for (k = 0; k < 2; ++k)
                for (i = 0; i < 3; ++i)
                    for (j = 0; j < 3; ++j) e->acc_q[k][i][j] += qv[k][i][j];
        e->acc_n++;
        e->acc_dt += dt;
        for (i = 0; i < 3; ++i) e->acc_f[i] += m->f_ned[i];
        if (e->nx == 21)
            for (i = 0; i < 3; ++i) {
                e->acc_fb[i] += fb[i];
                e->acc_w[i] += wb[i];
            }
        if (e->acc_n < e->cov_every) return;
        dt = e->acc_dt;
        for (i = 0; i < 3; ++i) {
            fn[i] = e->acc_f[i] / (ins_real)e->acc_n;
            fb[i] = e->acc_fb[i] / (ins_real)e->acc_n;
            wb[i] = e->acc_w[i] / (ins_real)e->acc_n;
            e->acc_f[i] = e->acc_fb[i] = e->acc_w[i] = K(0.0);
        }
        e->acc_n = 0;
        e->acc_dt = K(0.0);
        if (vib)
            for (k = 0; k < 2; ++k)
                for (i = 0; i < 3; ++i)
                    for (j = 0; j < 3; ++j) {
                        qv[k][i][j] = e->acc_q[k][i][j];
                        e->acc_q[k][i][j] = K(0.0);
                    }
    }
    for (i = 0; i < INS_NX; ++i) qd[i] = e->qc[i] * dt;
    propagate(e, m, c9, fn, dt, qd, vib ? qv : NULL, wb, fb);
}

void ins_ekf_predict_gap(ins_ekf_t *e, const ins_mech_t *m, const ins_real c9[9], ins_real gap) {
    /* ErrorStateEKF.predict_gap: F at the coasted state, the sensor noise over the gap and the unknown motion of
     * the gap: sigma_v = sa gap, sigma_r = sa gap^2 / 2, sigma_att = sw gap */
    const ins_real sa = e->gap_accel_sigma * gap, sw = e->gap_rate_sigma * gap;
    ins_real qd[INS_NX], wb[3] = {0, 0, 0}, fb[3];
    int i;
    for (i = 0; i < 3; ++i) /* C^T f_ned: the body specific force of the coasted state */
        fb[i] = c9[i] * m->f_ned[0] + c9[3 + i] * m->f_ned[1] + c9[6 + i] * m->f_ned[2];
    for (i = 0; i < INS_NX; ++i) qd[i] = e->qc[i] * gap;
    for (i = 0; i < 3; ++i) {
        const ins_real r = K(0.5) * sa * gap;
        qd[IR + i] += r * r;
        qd[IV + i] += sa * sa;
        qd[IA + i] += sw * sw;
    }
    propagate(e, m, c9, m->f_ned, gap, qd, NULL, wb, fb);
}

void ins_ekf_update_scalar(ins_ekf_t *e, const ins_real h[INS_NX], ins_real z, ins_real r) {
    /* Joseph form (book eqs. 3.16-3.18) for one scalar, as in ErrorStateEKF.update:
     *   k = P h / (h^T P h + r); x += k (z - h^T x); P = (I - k h^T) P (I - k h^T)^T + r k k^T,
     * evaluated as two rank-1 products: A = P - k (h^T P), P = A - (A h) k^T + r k k^T. */
    ins_real u[INS_NX], k[INS_NX], hp[INS_NX], ah[INS_NX];
    ins_real s = K(0.0), hx = K(0.0), innov;
    const int n = e->nx;
    int i, j;
    for (i = 0; i < n; ++i) {
        ins_real acc = K(0.0);
        for (j = 0; j < n; ++j) acc += e->P[i][j] * h[j];
        u[i] = acc; /* P h */
    }
    for (i = 0; i < n; ++i) {
        s += h[i] * u[i];
        hx += h[i] * e->x[i];
    }
    s += r;
    innov = z - hx;
    for (i = 0; i < n; ++i) {
        k[i] = u[i] / s; /* book eq. 3.17 */
        e->x[i] += k[i] * innov;
    }
    for (j = 0; j < n; ++j) {
        ins_real acc = K(0.0);
        for (i = 0; i < n; ++i) acc += h[i] * e->P[i][j];
        hp[j] = acc; /* h^T P */
    }
    for (i = 0; i < n; ++i)
        for (j = 0; j < n; ++j) e->P[i][j] -= k[i] * hp[j];
    for (i = 0; i < n; ++i) {
        ins_real acc = K(0.0);
        for (j = 0; j < n; ++j) acc += e->P[i][j] * h[j];
        ah[i] = acc; /* A h */
    }
    for (i = 0; i < n; ++i)
        for (j = 0; j < n; ++j) e->P[i][j] += -ah[i] * k[j] + r * k[i] * k[j];
}

void ins_ekf_symmetrize(ins_ekf_t *e) {
    const int n = e->nx;
    int i, j;
    for (i = 0; i < n; ++i)
        for (j = 0; j < i; ++j) e->P[i][j] = e->P[j][i] = K(0.5) * (e->P[i][j] + e->P[j][i]);
}

void ins_ekf_feedback(ins_ekf_t *e, ins_mech_t *m) {
    /* NavCore._feedback, operation by operation (radii at the old latitude, cos at the new one) */
    const ins_real lat = (ins_real)m->lat, h = (ins_real)m->h;
    const ins_real sl = RSIN(lat), w2 = K(1.0) - K(INS_E2_WGS84) * sl * sl, w = RS(w2);
    const ins_real rn = K(INS_A_WGS84) / w, rm = K(INS_A_WGS84) * (K(1.0) - K(INS_E2_WGS84)) / (w2 * w);
    ins_real dq[4], q[4], mpsi[3];
    int i;
    m->lat += (ins_pos)(e->x[IR + 0] / (rm + h));
    m->lon += (ins_pos)(e->x[IR + 1] / ((rn + h) * RCOS((ins_real)m->lat)));
    m->h -= (ins_pos)e->x[IR + 2];
    for (i = 0; i < 3; ++i) {
        m->v[i] += e->x[IV + i];
        mpsi[i] = -e->x[IA + i];
        e->bg[i] += e->x[IG + i];
        e->ba[i] += e->x[IB + i];
        if (e->nx == 21) {
            e->sg[i] += e->x[ISG + i];
            e->sa[i] += e->x[ISA + i];
        }
    }
    /* attitude: C <- (I - [psi x]) C_hat, i.e. q <- q(-psi) (x) q (DIGEST_000 section 9);
     * not renormalised here: the next mechanization step renormalises */
    ins_quat_from_rotvec(mpsi, dq);
    ins_quat_mul(dq, m->q, q);
    for (i = 0; i < 4; ++i) m->q[i] = q[i];
    for (i = 0; i < INS_NX; ++i) e->x[i] = K(0.0);
}
