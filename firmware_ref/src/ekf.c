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
 * Phi is written block by block (3x3, zero / diagonal / dense) from the generated blocks of F (phi_blocks), so a
 * predict is one block-sparse product A = Phi P (by rows, vectorised) and the upper triangle of A Phi^T.
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
    e->gate_only = 0;
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

/* Phi = I + F dt (+ F^2 dt^2 / 2) by 3x3 blocks (the 5 or 7 state groups r, v, psi, bg, ba (, sg, sa)): the
 * non-zero blocks of each block row (BLK_COL, BLK_NNZ: the pattern of the second-order Phi of the F of the generated
 * blocks; those a first-order Phi lacks are zero), each diagonal (r and the bias / scale-factor states on the block
 * diagonal: only its diagonal is read) or dense */
enum { NB = INS_NX / 3, BR = 0, BV = 1, BA = 2, BG = 3, BB = 4, BS = 5, BT = 6 };
static const unsigned char BLK_COL[2][NB][NB] = {
    {{BR, BV, BA, BB}, {BR, BV, BA, BG, BB}, {BA, BG}, {BG}, {BB}},
    {{BR, BV, BA, BB, BT}, {BR, BV, BA, BG, BB, BS, BT}, {BA, BG, BS}, {BG}, {BB}, {BS}, {BT}}};
static const unsigned char BLK_NNZ[2][NB] = {{4, 5, 2, 1, 1}, {5, 7, 3, 1, 1, 1, 1}};
#define BLK_DIAG(X, W) ((X) == (W) && (X) != BV && (X) != BA)
typedef struct {
    int nb;
    const unsigned char *nnz, (*col)[NB];
    ins_real b[NB][NB][3][3];
} bmat_t;

/* 3x3 kernels on a local block o (3 rows of 4: the fourth column a lane of the vector operations, not used) and blocks
 * of A (row stride INS_NX) or of Phi (rows of 4, the fourth 0) */
static inline void k_zero(ins_real o[12]) {
    int i;
    for (i = 0; i < 12; ++i) o[i] = K(0.0);
}
/* o += a f^T, given ft = f^T (the three columns j of a row at once: a0 ft[0][j] + a1 ft[1][j] + a2 ft[2][j], the
 * sum a0 f[j][0] + a1 f[j][1] + a2 f[j][2]) */
static inline void k_mact(ins_real o[12], const ins_real *a, ins_real ft[3][4]) {
    int i, j;
    for (i = 0; i < 3; ++i) {
        const ins_real a0 = a[i * INS_NX], a1 = a[i * INS_NX + 1], a2 = a[i * INS_NX + 2];
        for (j = 0; j < 4; ++j) o[4 * i + j] += a0 * ft[0][j] + a1 * ft[1][j] + a2 * ft[2][j];
    }
}
/* o += a f^T for an f whose last column f2 alone is non-zero */
static inline void k_mact2(ins_real o[12], const ins_real *a, const ins_real f2[4]) {
    int i, j;
    for (i = 0; i < 3; ++i)
        for (j = 0; j < 4; ++j) o[4 * i + j] += a[i * INS_NX + 2] * f2[j];
}
/* o += a diag(fd) (the fourth lane reads the next column of a, the next row's first past the last column) */
static inline void k_mactd(ins_real o[12], const ins_real *a, const ins_real fd[4]) {
    int i, j;
    for (i = 0; i < 3; ++i)
        for (j = 0; j < 4; ++j) o[4 * i + j] += a[i * INS_NX + j] * fd[j];
}
#define AB(X, Z) (&a[3 * (X)][3 * (Z)])

#define CB(x) ((const ins_real(*)[3])(x))

/* (a b)[i][j] (3x3) for a skew-symmetric a (F_vv, F_vpsi, F_psipsi: zero diagonal, checked by derive_jacobians.py):
 * the sum a[i][0] b[0][j] + a[i][1] b[1][j] + a[i][2] b[2][j] without its exact zero term a[i][i] b[i][j] */
static inline ins_real m3e(const ins_real a[3][3], const ins_real b[3][3], const int i, const int j) {
    return i == 0 ? a[0][1] * b[1][j] + a[0][2] * b[2][j]
                  : i == 1 ? a[1][0] * b[0][j] + a[1][2] * b[2][j] : a[2][0] * b[0][j] + a[2][1] * b[1][j];
}

/* The entries of one block O of Phi: o = A + h2 (0 + S - C) (A: dt a or 0; S: h2's sum of products; C: t c or 0),
 * then + E on the diagonal if HAS_E (the identity, or dt), each entry one expression of the F blocks: no 3x3 products
 * stored entry by entry and read back in pairs (a store-forwarding stall) */
#define PHI_BLK(O, A, S, C, HAS_E, E)                                                                                  \
    do {                                                                                                               \
        int i, j;                                                                                                      \
        for (i = 0; i < 3; ++i)                                                                                        \
            for (j = 0; j < 3; ++j) {                                                                                  \
                ins_real q_ = K(0.0), o_;                                                                              \
                q_ += (S);                                                                                             \
                q_ -= (C);                                                                                             \
                o_ = (A) + h2 * q_;                                                                                    \
                (O)[i][j] = HAS_E && i == j ? o_ + (E) : o_;                                                           \
            }                                                                                                          \
    } while (0)

/* Phi = I + F dt (+ F^2 dt^2 / 2) block by block from the generated blocks of F (generated/ins_jacobians.h; the block
 * structure derive_jacobians.py checks: F_rv = I, F_vr = diag(0, 0, 2 g / R), the v and psi blocks, -1/tau on the
 * diagonal of the bias / scale-factor rows). The F^2 blocks written out: row r of F^2 is row v of F; row v:
 * F_vr F_r + F_vv F_v + F_vpsi F_psi + F_vba F_ba (+ F_vsa F_sa); row psi: F_psipsi F_psi + F_psibg F_bg (+ F_psisg
 * F_sg); the diagonal rows their squares. (Checked against the product of the full F by tests/test_firmware.py's
 * parity with the Python filter, which forms F @ F.) */
static void phi_blocks(bmat_t *phi, int nb, const ins_gen_fblocks_t *g, const ins_gen_fsf_t *sf, ins_real itg,
                       ins_real ita, ins_real its, ins_real dt, int second) {
    const ins_real h2 = second ? K(0.5) * dt * dt : K(0.0), d = g->vr_dd;
    ins_real(*o)[3];
    int k;
    phi->nb = nb;
    phi->nnz = BLK_NNZ[nb == NB];
    phi->col = BLK_COL[nb == NB];
    o = phi->b[BR][BR]; /* I + h2 D, D = F_vr = diag(0, 0, d) */
    o[0][0] = o[1][1] = K(1.0);
    o[2][2] = K(1.0) + h2 * d;
    PHI_BLK(phi->b[BR][BV], K(0.0), g->vv[i][j], K(0.0), 1, dt); /* r v: I dt + h2 F_vv */
    PHI_BLK(phi->b[BR][BA], K(0.0), g->va[i][j], K(0.0), 0, K(0.0)); /* r psi: h2 F_vpsi */
    PHI_BLK(phi->b[BR][BB], K(0.0), g->vba[i][j], K(0.0), 0, K(0.0)); /* r ba: h2 F_vba */
    o = phi->b[BV][BR]; /* dt D + h2 F_vv D: column d only */
    for (k = 0; k < 3; ++k) {
        o[k][0] = o[k][1] = K(0.0);
        o[k][2] = h2 * (g->vv[k][2] * d);
    }
    o[2][2] += dt * d;
    /* vv: I + dt F_vv + h2 (D + F_vv F_vv) */
    PHI_BLK(phi->b[BV][BV], dt * g->vv[i][j], i == 2 && j == 2 ? m3e(g->vv, g->vv, 2, 2) + d : m3e(g->vv, g->vv, i, j),
            K(0.0), 1, K(1.0));
    /* v psi: dt F_vpsi + h2 (F_vv F_vpsi + F_vpsi F_psipsi) */
    PHI_BLK(phi->b[BV][BA], dt * g->va[i][j], m3e(g->vv, g->va, i, j) + m3e(g->va, g->aa, i, j), K(0.0), 0, K(0.0));
    /* v bg: h2 F_vpsi F_psibg */
    PHI_BLK(phi->b[BV][BG], K(0.0), m3e(g->va, g->abg, i, j), K(0.0), 0, K(0.0));
    /* v ba: dt F_vba + h2 (F_vv F_vba - F_vba / tau_a) */
    PHI_BLK(phi->b[BV][BB], dt * g->vba[i][j], m3e(g->vv, g->vba, i, j), ita * g->vba[i][j], 0, K(0.0));
    /* psi psi: I + dt F_psipsi + h2 F_psipsi^2 */
    PHI_BLK(phi->b[BA][BA], dt * g->aa[i][j], m3e(g->aa, g->aa, i, j), K(0.0), 1, K(1.0));
    /* psi bg: dt F_psibg + h2 (F_psipsi F_psibg - F_psibg / tau_g) */
    PHI_BLK(phi->b[BA][BG], dt * g->abg[i][j], m3e(g->aa, g->abg, i, j), itg * g->abg[i][j], 0, K(0.0));
    for (k = 0; k < 3; ++k) {
        phi->b[BG][BG][k][k] = K(1.0) - dt * itg + h2 * (itg * itg);
        phi->b[BB][BB][k][k] = K(1.0) - dt * ita + h2 * (ita * ita);
    }
    if (nb == NB) {
        PHI_BLK(phi->b[BR][BT], K(0.0), sf->vsa[i][j], K(0.0), 0, K(0.0));
        /* v sg: h2 F_vpsi F_psisg */
        PHI_BLK(phi->b[BV][BS], K(0.0), m3e(g->va, sf->asg, i, j), K(0.0), 0, K(0.0));
        /* v sa: dt F_vsa + h2 (F_vv F_vsa - F_vsa / tau_s) */
        PHI_BLK(phi->b[BV][BT], dt * sf->vsa[i][j], m3e(g->vv, sf->vsa, i, j), its * sf->vsa[i][j], 0, K(0.0));
        /* psi sg: dt F_psisg + h2 (F_psipsi F_psisg - F_psisg / tau_s) */
        PHI_BLK(phi->b[BA][BS], dt * sf->asg[i][j], m3e(g->aa, sf->asg, i, j), its * sf->asg[i][j], 0, K(0.0));
        for (k = 0; k < 3; ++k)
            phi->b[BS][BS][k][k] = phi->b[BT][BT][k][k] = K(1.0) - dt * its + h2 * (its * its);
    }
}

/* a = phi p, block row X from column j0 (0 for r, v; 3 X after: the upper triangle of the result reads no
 * more of it) on: the three rows at once, each a combination of the rows of p the
 * non-zero blocks of the block row pick, over contiguous columns (vectorised); n a constant in each inlined copy */
static inline void phi_p_rows(const bmat_t *phi, ins_real p[INS_NX][INS_NX], ins_real a[INS_NX][INS_NX], const int n) {
    int X, k, j;
    for (X = 0; X < phi->nb; ++X) {
        const int j0 = X <= BV ? 0 : (3 * X) & ~1; /* even: whole pairs of columns (vectorised) */
        ins_real *o0 = a[3 * X], *o1 = a[3 * X + 1], *o2 = a[3 * X + 2];
        for (k = 0; k < phi->nnz[X]; ++k) {
            const int W = phi->col[X][k];
            const ins_real(*b)[3] = phi->b[X][W];
            const ins_real *x0 = p[3 * W], *x1 = p[3 * W + 1], *x2 = p[3 * W + 2];
            if (X == BV && W == BR) { /* dt D + h2 F_vv D: its last column alone is non-zero; first in its row */
                const ins_real d0 = b[0][2], d1 = b[1][2], d2 = b[2][2];
                for (j = j0; j < n; ++j) {
                    o0[j] = K(0.0) + d0 * x2[j];
                    o1[j] = K(0.0) + d1 * x2[j];
                    o2[j] = K(0.0) + d2 * x2[j];
                }
            } else if (BLK_DIAG(X, W)) { /* a diagonal block: the first of its row (BLK_COL) */
                const ins_real d0 = b[0][0], d1 = b[1][1], d2 = b[2][2];
                for (j = j0; j < n; ++j) {
                    o0[j] = K(0.0) + d0 * x0[j];
                    o1[j] = K(0.0) + d1 * x1[j];
                    o2[j] = K(0.0) + d2 * x2[j];
                }
            } else if (k == 0) { /* psi row: the sums start at 0 + the first block's (as before: o = 0, o += ...) */
                const ins_real b00 = b[0][0], b01 = b[0][1], b02 = b[0][2], b10 = b[1][0], b11 = b[1][1];
                const ins_real b12 = b[1][2], b20 = b[2][0], b21 = b[2][1], b22 = b[2][2];
                for (j = j0; j < n; ++j) {
                    const ins_real v0 = x0[j], v1 = x1[j], v2 = x2[j];
                    o0[j] = K(0.0) + (b00 * v0 + b01 * v1 + b02 * v2);
                    o1[j] = K(0.0) + (b10 * v0 + b11 * v1 + b12 * v2);
                    o2[j] = K(0.0) + (b20 * v0 + b21 * v1 + b22 * v2);
                }
            } else {
                const ins_real b00 = b[0][0], b01 = b[0][1], b02 = b[0][2], b10 = b[1][0], b11 = b[1][1];
                const ins_real b12 = b[1][2], b20 = b[2][0], b21 = b[2][1], b22 = b[2][2];
                for (j = j0; j < n; ++j) {
                    const ins_real v0 = x0[j], v1 = x1[j], v2 = x2[j];
                    o0[j] += b00 * v0 + b01 * v1 + b02 * v2;
                    o1[j] += b10 * v0 + b11 * v1 + b12 * v2;
                    o2[j] += b20 * v0 + b21 * v1 + b22 * v2;
                }
            }
        }
    }
}

/* P <- Phi P Phi^T on the 3x3 blocks of Phi: A = Phi P (phi_p_rows), then P[X][Y] = sum_Z A[X][Z] Phi[Y][Z]^T
 * for X <= Y, mirrored into the lower triangle. */
INS_HOT
static void phi_p_phit(const bmat_t *phi, ins_real p[INS_NX][INS_NX]) {
    ins_real a[INS_NX + 1][INS_NX], o[12], ft[NB][NB][3][4], fd[NB][4], f2[4];
    const int nb = phi->nb, sf = nb == NB;
    int X, Y, i, j;
    for (Y = 0; Y <= BA; ++Y) /* the transposed dense blocks of Phi (k_mact) */
        for (X = Y == BA ? BA : BV; X < nb; ++X)
            for (i = 0; i < 3; ++i) {
                for (j = 0; j < 3; ++j) ft[Y][X][i][j] = phi->b[Y][X][j][i];
                ft[Y][X][i][3] = K(0.0);
            }
    for (Y = 0; Y < nb; ++Y) /* the diagonals of the diagonal blocks */
        for (j = 0; j < 4; ++j) fd[Y][j] = j < 3 && Y != BV && Y != BA ? phi->b[Y][Y][j][j] : K(0.0);
    for (j = 0; j < 3; ++j) f2[j] = phi->b[BV][BR][j][2];
    f2[3] = K(0.0);
    for (j = 0; j < INS_NX; ++j) a[INS_NX][j] = K(0.0); /* the last rows' fourth lane (k_mactd, 21 states) */
    for (i = 6; i < INS_NX; ++i) a[i][0] = K(0.0);        /* the rows before (their column 0: not formed) */
    if (sf) phi_p_rows(phi, p, a, INS_NX);
    else phi_p_rows(phi, p, a, 16); /* + column 15 of the 15-state P (whole pairs of columns; A[.][15] is not read) */
    for (Y = 0; Y < nb; ++Y)
        for (X = 0; X <= Y; ++X) {
            k_zero(o);
            if (Y == BR) {
                k_mactd(o, AB(X, BR), fd[BR]);
                k_mact(o, AB(X, BV), ft[BR][BV]);
                k_mact(o, AB(X, BA), ft[BR][BA]);
                k_mact(o, AB(X, BB), ft[BR][BB]);
                if (sf) k_mact(o, AB(X, BT), ft[BR][BT]);
            } else if (Y == BV) {
                k_mact2(o, AB(X, BR), f2);
                k_mact(o, AB(X, BV), ft[BV][BV]);
                k_mact(o, AB(X, BA), ft[BV][BA]);
                k_mact(o, AB(X, BG), ft[BV][BG]);
                k_mact(o, AB(X, BB), ft[BV][BB]);
                if (sf) {
                    k_mact(o, AB(X, BS), ft[BV][BS]);
                    k_mact(o, AB(X, BT), ft[BV][BT]);
                }
            } else if (Y == BA) {
                k_mact(o, AB(X, BA), ft[BA][BA]);
                k_mact(o, AB(X, BG), ft[BA][BG]);
                if (sf) k_mact(o, AB(X, BS), ft[BA][BS]);
            } else {
                k_mactd(o, AB(X, Y), fd[Y]);
            }
            for (i = 0; i < 3; ++i)
                for (j = X < Y ? 0 : i; j < 3; ++j) p[3 * X + i][3 * Y + j] = p[3 * Y + j][3 * X + i] = o[4 * i + j];
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
    ins_gen_fblocks_t g;
    ins_gen_fsf_t sf;
    bmat_t phi;
    const int n = e->nx;
    int i, j;
    if (n == 21) ins_gen_F_sf(c9, fb, wb, &sf);
    /* d g / d(down) = +2 g / R (seed 001 eq. 96, corrected sign; DIGEST_001_004 section 1.9) */
    ins_gen_F_blocks(c9, fn, m->omega_ie, m->omega_en, K(2.0 * 9.80665 / 6371000.0), &g);
    phi_blocks(&phi, n / 3, &g, &sf, e->inv_tau_g, e->inv_tau_a, e->inv_tau_s, dt, e->second_order);
    phi_p_phit(&phi, e->P);
    for (i = 0; i < n; ++i) e->P[i][i] += qd[i];
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

/* P = (P - k hp^T) + (-(A h) k^T + r k k^T) on the n x n block (n a constant in each inlined copy) */
static inline void rank2(ins_real p[INS_NX][INS_NX], const ins_real k[INS_NX], const ins_real hp[INS_NX],
                         const ins_real ah[INS_NX], ins_real r, const int n) {
    int i, j;
    for (i = 0; i < n; ++i) {
        const ins_real ki = k[i], ai = ah[i];
        for (j = 0; j < n; ++j) p[i][j] = (p[i][j] - ki * hp[j]) + (-ai * k[j] + r * ki * k[j]);
    }
}

INS_HOT void ins_ekf_update_scalar(ins_ekf_t *e, const ins_real h[INS_NX], ins_real z, ins_real r) {
    /* Joseph form (book eqs. 3.16-3.18) for one scalar, as in ErrorStateEKF.update:
     *   k = P h / (h^T P h + r); x += k (z - h^T x); P = (I - k h^T) P (I - k h^T)^T + r k k^T,
     * evaluated as two rank-1 products: A = P - k (h^T P), P = A - (A h) k^T + r k k^T. */
    ins_real u[INS_NX], k[INS_NX], hp[INS_NX], ah[INS_NX], hv[INS_NX];
    ins_real s = K(0.0), hx = K(0.0), innov;
    const int n = e->nx;
    int i, j, t, m = 0;
    unsigned char nz[INS_NX];
    /* the products with h over its non-zero entries only (a measurement row touches a few states): the sums of
     * the full products less their exact zero terms, so the same numbers */
    for (j = 0; j < n; ++j)
        if (h[j] != K(0.0)) {
            nz[m] = (unsigned char)j;
            hv[m++] = h[j];
        }
    for (i = 0; i < n; ++i) {
        ins_real acc = K(0.0);
        for (t = 0; t < m; ++t) acc += e->P[i][nz[t]] * hv[t];
        u[i] = acc; /* P h */
    }
    for (t = 0; t < m; ++t) {
        s += hv[t] * u[nz[t]];
        hx += hv[t] * e->x[nz[t]];
    }
    s += r;
    innov = z - hx;
    for (i = 0; i < n; ++i) {
        k[i] = u[i] / s; /* book eq. 3.17 */
        e->x[i] += k[i] * innov;
    }
    for (j = 0; j < n; ++j) {
        ins_real acc = K(0.0);
        for (t = 0; t < m; ++t) acc += hv[t] * e->P[nz[t]][j];
        hp[j] = acc; /* h^T P */
    }
    for (i = 0; i < n; ++i) { /* A = P - k hp, A h from the same rounded entries, then P = A - (A h) k^T + r k k^T */
        ins_real acc = K(0.0);
        for (t = 0; t < m; ++t) acc += (e->P[i][nz[t]] - k[i] * hp[nz[t]]) * hv[t];
        ah[i] = acc;
    }
    if (n == 15) rank2(e->P, k, hp, ah, r, 15);
    else rank2(e->P, k, hp, ah, r, INS_NX);
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
