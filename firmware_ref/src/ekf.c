/* 15-state error-state EKF: predict every IMU step, Joseph-form sequential
 * scalar updates, feedback and reset.
 *
 * Model (NED form of seed 001 eqs. 83-101, DIGEST_001_004 section 1.9, with
 * the sign convention of DIGEST_000 section 9: dr, dv = true - computed,
 * C_hat = (I + [psi x]) C, bias errors = true - estimated):
 *   d(dr)/dt  = dv
 *   d(dv)/dt  = [f_n x] psi - (2 w_ie + w_en) x dv - C_b^n dba + (0, 0, 2 g/R dr_D)
 *   d(psi)/dt = -w_in x psi + C_b^n dbg         (book eq. 3.40, seed 001 eq. 98)
 *   d(db)/dt  = -db / tau (+ white noise)        (seed 001 eqs. 87/88)
 * Discretised as Phi = I + F dt (book eq. 3.2 to first order), P = Phi P Phi^T + Q
 * (book eq. 3.19), Q diagonal: VRW^2 dt, ARW^2 dt, 2 sigma_b^2 dt / tau.
 */
#include "ins_internal.h"

enum { IR = 0, IV = 3, IA = 6, IG = 9, IB = 12 };

void ins_ekf_default_cfg(ins_ekf_cfg_t *cfg) {
    const double deg = 3.14159265358979323846 / 180.0;
    cfg->gyro_arw = K(0.15 * deg / 60.0);         /* 0.15 deg/sqrt(h) */
    cfg->accel_vrw = K(70e-6 * 9.80665);          /* 70 ug/sqrt(Hz) */
    cfg->gyro_bias_sigma = K(10.0 * deg / 3600.0); /* 10 deg/h */
    cfg->gyro_bias_tau = K(300.0);
    cfg->accel_bias_sigma = K(0.1e-3 * 9.80665);   /* 0.1 mg */
    cfg->accel_bias_tau = K(300.0);
    cfg->p0_pos = K(5.0);
    cfg->p0_vel = K(0.5);
    cfg->p0_att = K(2.0 * deg);
    cfg->p0_bg = K(0.2 * deg);
    cfg->p0_ba = K(20e-3 * 9.80665);
    cfg->baro_offset = K(0.0);
}

static void bias_noise(ins_real sigma, ins_real tau, ins_real dt, ins_real *q, ins_real *f) {
    if (tau > K(0.0)) {
        *q = K(2.0) * sigma * sigma * dt / tau; /* first-order Gauss-Markov */
        *f = K(1.0) - dt / tau;
    } else {
        *q = sigma * sigma * dt; /* random walk: sigma is the rate density */
        *f = K(1.0);
    }
}

void ins_ekf_init(ins_ekf_t *e, const ins_ekf_cfg_t *cfg, ins_real dt) {
    int i, j;
    ins_real qg, qa;
    const ins_real p0[5] = {cfg->p0_pos, cfg->p0_vel, cfg->p0_att, cfg->p0_bg, cfg->p0_ba};
    for (i = 0; i < INS_NX; ++i) {
        for (j = 0; j < INS_NX; ++j) e->P[i][j] = K(0.0);
        e->P[i][i] = p0[i / 3] * p0[i / 3];
        e->x[i] = K(0.0);
    }
    for (i = 0; i < 3; ++i) e->bg[i] = e->ba[i] = K(0.0);
    bias_noise(cfg->gyro_bias_sigma, cfg->gyro_bias_tau, dt, &qg, &e->fg);
    bias_noise(cfg->accel_bias_sigma, cfg->accel_bias_tau, dt, &qa, &e->fa);
    for (i = 0; i < 3; ++i) {
        e->qd[IR + i] = K(0.0);
        e->qd[IV + i] = cfg->accel_vrw * cfg->accel_vrw * dt;
        e->qd[IA + i] = cfg->gyro_arw * cfg->gyro_arw * dt;
        e->qd[IG + i] = qg;
        e->qd[IB + i] = qa;
    }
    e->baro_offset = cfg->baro_offset;
    e->n_updates = 0;
    e->last_nis = K(0.0);
}

/* out = Phi * in, Phi = I + F dt, exploiting the block sparsity of F. */
typedef struct {
    ins_real dt, fg, fa, g2r;
    ins_real vv[3][3]; /* -(2 w_ie + w_en) x */
    ins_real va[3][3]; /* [f x] */
    ins_real aa[3][3]; /* -w_in x */
    ins_real c[3][3];  /* C_b^n */
} phi_t;

static void phi_mul(const phi_t *f, ins_real in[INS_NX][INS_NX], ins_real out[INS_NX][INS_NX]) {
    int i, j, k;
    const ins_real dt = f->dt;
    for (j = 0; j < INS_NX; ++j) {
        for (i = 0; i < 3; ++i) {
            ins_real sv = K(0.0), sa = K(0.0);
            out[IR + i][j] = in[IR + i][j] + dt * in[IV + i][j];
            for (k = 0; k < 3; ++k) {
                sv += f->vv[i][k] * in[IV + k][j] + f->va[i][k] * in[IA + k][j] - f->c[i][k] * in[IB + k][j];
                sa += f->aa[i][k] * in[IA + k][j] + f->c[i][k] * in[IG + k][j];
            }
            if (i == 2) sv += f->g2r * in[IR + 2][j];
            out[IV + i][j] = in[IV + i][j] + dt * sv;
            out[IA + i][j] = in[IA + i][j] + dt * sa;
            out[IG + i][j] = f->fg * in[IG + i][j];
            out[IB + i][j] = f->fa * in[IB + i][j];
        }
    }
}

static void skew_into(ins_real m[3][3], ins_real x, ins_real y, ins_real z, ins_real s) {
    /* m = s [v x] */
    m[0][0] = K(0.0);
    m[0][1] = -s * z;
    m[0][2] = s * y;
    m[1][0] = s * z;
    m[1][1] = K(0.0);
    m[1][2] = -s * x;
    m[2][0] = -s * y;
    m[2][1] = s * x;
    m[2][2] = K(0.0);
}

void ins_ekf_predict(ins_ekf_t *e, const ins_mech_t *m) {
    phi_t f;
    ins_real a[INS_NX][INS_NX], at[INS_NX][INS_NX], c9[9];
    const ins_real *wie = m->omega_ie, *wen = m->omega_en;
    int i, j;
    f.dt = m->dt;
    f.fg = e->fg;
    f.fa = e->fa;
    /* d g / d(down) = +2 g / R (seed 001 eq. 96, corrected sign; DIGEST_001_004 section 1.9) */
    f.g2r = K(2.0 * 9.80665 / 6371000.0);
    skew_into(f.vv, K(2.0) * wie[0] + wen[0], K(2.0) * wie[1] + wen[1], K(2.0) * wie[2] + wen[2], K(-1.0));
    skew_into(f.va, m->f_ned[0], m->f_ned[1], m->f_ned[2], K(1.0));
    skew_into(f.aa, wie[0] + wen[0], wie[1] + wen[1], wie[2] + wen[2], K(-1.0));
    ins_dcm_from_quat(m->q, c9);
    for (i = 0; i < 3; ++i)
        for (j = 0; j < 3; ++j) f.c[i][j] = c9[3 * i + j];
    phi_mul(&f, e->P, a); /* A = Phi P */
    for (i = 0; i < INS_NX; ++i)
        for (j = 0; j < INS_NX; ++j) at[i][j] = a[j][i];
    phi_mul(&f, at, a); /* Phi (Phi P)^T = Phi P Phi^T */
    for (i = 0; i < INS_NX; ++i) {
        for (j = 0; j < i; ++j) e->P[i][j] = e->P[j][i] = K(0.5) * (a[i][j] + a[j][i]);
        e->P[i][i] = a[i][i] + e->qd[i];
    }
    /* the error state itself is zero between updates (reset after feedback): x = Phi x = 0 */
}

ins_real ins_ekf_update_scalar(ins_ekf_t *e, const ins_real h[INS_NX], ins_real z, ins_real r) {
    /* Joseph form (book eq. 3.16-3.18) for one scalar measurement, as two rank-1 products:
     *   A = (I - K h^T) P,  P+ = A (I - K h^T)^T + K r K^T. */
    ins_real u[INS_NX], k[INS_NX], hp[INS_NX], ah[INS_NX];
    ins_real s = r, innov = z, nis;
    int i, j;
    for (i = 0; i < INS_NX; ++i) {
        ins_real acc = K(0.0);
        for (j = 0; j < INS_NX; ++j) acc += e->P[i][j] * h[j];
        u[i] = acc; /* P h */
        innov -= h[i] * e->x[i];
    }
    for (i = 0; i < INS_NX; ++i) s += h[i] * u[i];
    for (i = 0; i < INS_NX; ++i) k[i] = u[i] / s; /* book eq. 3.17 */
    for (j = 0; j < INS_NX; ++j) {
        ins_real acc = K(0.0);
        for (i = 0; i < INS_NX; ++i) acc += h[i] * e->P[i][j];
        hp[j] = acc; /* h^T P */
    }
    for (i = 0; i < INS_NX; ++i)
        for (j = 0; j < INS_NX; ++j) e->P[i][j] -= k[i] * hp[j]; /* A = P - K h^T P */
    for (i = 0; i < INS_NX; ++i) {
        ins_real acc = K(0.0);
        for (j = 0; j < INS_NX; ++j) acc += e->P[i][j] * h[j];
        ah[i] = acc; /* A h */
    }
    for (i = 0; i < INS_NX; ++i)
        for (j = 0; j < INS_NX; ++j) e->P[i][j] += -ah[i] * k[j] + r * k[i] * k[j];
    for (i = 0; i < INS_NX; ++i) {
        e->x[i] += k[i] * innov;
        for (j = 0; j < i; ++j) e->P[i][j] = e->P[j][i] = K(0.5) * (e->P[i][j] + e->P[j][i]);
    }
    nis = innov * innov / s;
    e->last_nis = nis;
    e->n_updates++;
    return nis;
}

void ins_ekf_feedback(ins_ekf_t *e, ins_mech_t *m) {
    const ins_real lat = (ins_real)m->lat, h = (ins_real)m->h;
    const ins_real sl = RSIN(lat), w2 = K(1.0) - K(INS_E2_WGS84) * sl * sl;
    const ins_real rn = K(INS_A_WGS84) / RS(w2), rm = rn * (K(1.0) - K(INS_E2_WGS84)) / w2;
    ins_real dq[4], q[4], mpsi[3];
    int i;
    /* position and velocity: true = computed + error */
    m->lat += (ins_pos)(e->x[IR + 0] / (rm + h));
    m->lon += (ins_pos)(e->x[IR + 1] / ((rn + h) * RCOS(lat)));
    m->h -= (ins_pos)e->x[IR + 2];
    for (i = 0; i < 3; ++i) {
        m->v[i] += e->x[IV + i];
        mpsi[i] = -e->x[IA + i];
        e->bg[i] += e->x[IG + i];
        e->ba[i] += e->x[IB + i];
    }
    /* attitude: C <- (I - [psi x]) C_hat, i.e. q <- q(-psi) (x) q (DIGEST_000 section 9) */
    ins_quat_from_rotvec(mpsi, dq);
    ins_quat_mul(dq, m->q, q);
    for (i = 0; i < 4; ++i) m->q[i] = q[i];
    ins_quat_normalize(m->q);
    for (i = 0; i < INS_NX; ++i) e->x[i] = K(0.0);
}
