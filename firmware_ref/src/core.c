/* The core: mechanization + EKF predict per IMU step, GNSS/baro updates. */
#include "ins_internal.h"
#include "generated/ins_jacobians.h"
#include <string.h>

void ins_core_init(ins_core_t *c, const ins_real q[4], const ins_real v[3], ins_pos lat, ins_pos lon, ins_pos h,
                   double t, ins_real dt, const ins_ekf_cfg_t *cfg, int filter) {
    ins_ekf_cfg_t def;
    if (cfg == NULL) {
        ins_ekf_default_cfg(&def);
        cfg = &def;
    }
    ins_mech_init(&c->mech, q, v, lat, lon, h, t, dt);
    ins_ekf_init(&c->ekf, cfg);
    c->filter = filter;
    c->steps = 0;
    c->pub = NULL;
}

static void ground_aids(ins_core_t *c, const ins_real w_b[3]);
static void hold(ins_core_t *c);

void ins_core_step(ins_core_t *c, const ins_real dth[3], const ins_real dv[3], double t_end) {
    ins_real a[3], u[3];
    const ins_real dt = c->mech.dt;
    int i;
    for (i = 0; i < 3; ++i) { /* bias-corrected increments (book eq. 3.45) */
        a[i] = dth[i] - c->ekf.bg[i] * dt;
        u[i] = dv[i] - c->ekf.ba[i] * dt;
    }
    if (c->ekf.nx == 21)
        for (i = 0; i < 3; ++i) { /* and scale-factor corrected (NavCore._mechanize) */
            a[i] = a[i] / (K(1.0) + c->ekf.sg[i]);
            u[i] = u[i] / (K(1.0) + c->ekf.sa[i]);
        }
    ins_mech_step(&c->mech, a, u);
    c->mech.t = t_end;
    if (c->pub != NULL && !c->ekf.replaying) ins_core_output(c, c->pub);
    if (c->filter) {
        ins_real w_b[3], f_b[3];
        for (i = 0; i < 3; ++i) {
            w_b[i] = a[i] / dt;
            f_b[i] = u[i] / dt;
        }
        ins_ekf_predict_full(&c->ekf, &c->mech, w_b, f_b);
        ground_aids(c, w_b);
    }
    c->steps++;
    if (c->filter && c->ekf.hold && !c->ekf.replaying) hold(c);
}

/* NavCore._coast: cross lost s of lost IMU data at constant velocity and attitude, covariance grown */
static void coast(ins_core_t *c, double lost) {
    ins_mech_t *m = &c->mech;
    const ins_real dt = m->dt, zero[3] = {0, 0, 0};
    const double t_end = m->t + lost;
    ins_real c9[9], u[3], g2, d;
    int i;
    m->have_prev = 0;
    ins_dcm_from_quat(m->q, c9);
    d = (ins_real)(lost < 10.0 ? lost : 10.0); /* GAP_MAX_S */
    g2 = -c->ekf.g_local * d;                  /* the specific force of no acceleration (NED), over the gap */
    for (i = 0; i < 3; ++i) u[i] = c9[i] * K(0.0) + c9[3 + i] * K(0.0) + c9[6 + i] * g2; /* C^T g */
    m->dt = d;
    ins_mech_step(m, zero, u);
    m->dt = dt;
    m->have_prev = 0;
    m->t = t_end;
    if (c->filter) ins_ekf_predict_gap(&c->ekf, m, c9, d);
}

void ins_core_step_dt(ins_core_t *c, const ins_real dth[3], const ins_real dv[3], double t_end, ins_real dt) {
    double lost;
    c->mech.dt = dt;
    lost = t_end - (double)dt - c->mech.t;
    if (lost > 0.5 * (double)dt && c->steps > 0) coast(c, lost);
    ins_core_step(c, dth, dv, t_end);
}

void ins_core_run(ins_core_t *c, const ins_real *inc, const double *t_end, size_t n, ins_out_t *out) {
    size_t k;
    for (k = 0; k < n; ++k) {
        const double te = t_end != NULL ? t_end[k] : c->mech.t + (double)c->mech.dt;
        ins_core_step(c, inc + 6 * k, inc + 6 * k + 3, te);
        if (out != NULL) ins_core_output(c, out + k);
    }
}

static void radii(ins_real lat, ins_real *m, ins_real *n) {
    /* ins_hil.nav.earth.radii: seed 001 eqs. 2, 3 */
    const ins_real sl = RSIN(lat), w2 = K(1.0) - K(INS_E2_WGS84) * sl * sl, w = RS(w2);
    *n = K(INS_A_WGS84) / w;
    *m = K(INS_A_WGS84) * (K(1.0) - K(INS_E2_WGS84)) / (w2 * w);
}

/* P block k..k+2 := diag(sd^2), correlations cleared (ErrorStateEKF.set_state_sigma) */
static void set_state_sigma(ins_ekf_t *e, int k, const ins_real sd[3]) {
    int i, j;
    for (i = k; i < k + 3; ++i)
        for (j = 0; j < INS_NX; ++j) e->P[i][j] = e->P[j][i] = K(0.0);
    for (i = 0; i < 3; ++i) e->P[k + i][k + i] = sd[i] * sd[i];
}

/* One measurement group of n rows h (n x INS_NX), as NavCore._apply: per-component gate z_i^2 / (g^2 S_ii),
 * S_ii = h_i P h_i^T + r_i (forced acceptance of a GNSS position after gnss_reset_after rejections), sequential
 * scalar Joseph updates, symmetrise, feedback. Returns 1 if accepted. */
static int apply_rows(ins_core_t *c, int grp, int n, ins_real h[][INS_NX], const ins_real *z, const ins_real *r) {
    ins_ekf_t *e = &c->ekf;
    ins_real ratio = K(0.0);
    const ins_real g2 = e->gate[grp] * e->gate[grp];
    int i, j, k, m, force;
    unsigned char nz[INS_NX];
    for (i = 0; i < n; ++i) {
        ins_real s = K(0.0), q;
        for (k = 0, m = 0; k < INS_NX; ++k) /* the row's non-zero entries (the zero terms add an exact +-0) */
            if (h[i][k] != K(0.0)) nz[m++] = (unsigned char)k;
        for (j = 0; j < m; ++j) {
            ins_real acc = K(0.0);
            for (k = 0; k < m; ++k) acc += e->P[nz[j]][nz[k]] * h[i][nz[k]];
            s += h[i][nz[j]] * acc;
        }
        s += r[i];
        q = z[i] * z[i] / (g2 * s);
        if (q > ratio || i == 0) ratio = q;
    }
    e->last_ratio[grp] = ratio;
    force = grp == INS_GRP_GNSS_POS && (int)e->consecutive[grp] >= e->gnss_reset_after;
    if (ratio > K(1.0) && !force) {
        if (!e->replaying) {
            e->rejected[grp]++;
            e->consecutive[grp]++;
        }
        return 0;
    }
    if (!e->replaying) {
        e->accepted[grp]++;
        e->consecutive[grp] = 0;
    }
    if (e->gate_only) return 1; /* the update is a roll-back replay's (ins_hist_fuse_gnss_split) */
    for (i = 0; i < n; ++i) ins_ekf_update_scalar(e, h[i], z[i], r[i]);
    ins_ekf_symmetrize(e);
    ins_ekf_feedback(e, &c->mech);
    return 1;
}

/* n zero rows */
static void zero_rows(ins_real h[][INS_NX], int n) {
    int i, j;
    for (i = 0; i < n; ++i)
        for (j = 0; j < INS_NX; ++j) h[i][j] = K(0.0);
}

static void mat_vec(const ins_real m[9], const ins_real v[3], ins_real out[3]) {
    int i;
    for (i = 0; i < 3; ++i) out[i] = m[3 * i] * v[0] + m[3 * i + 1] * v[1] + m[3 * i + 2] * v[2];
}

static ins_real maxr(ins_real a, ins_real b) { return a > b ? a : b; }

int ins_core_fuse_gnss(ins_core_t *c, const ins_gnss_t *g) {
    return ins_core_fuse_gnss_at(c, g, g->t < c->mech.t - 1.5 * (double)c->mech.dt); /* late fix: valid now */
}

int ins_core_fuse_gnss_at(ins_core_t *c, const ins_gnss_t *g, int assume_now) {
    ins_mech_t *m = &c->mech;
    ins_ekf_t *e = &c->ekf;
    const ins_real sne = maxr(g->std_ne, e->min_std[0]) * e->std_scale;
    const ins_real sd = maxr(g->std_d, e->min_std[1]) * e->std_scale;
    const ins_real lat = (ins_real)m->lat, h = (ins_real)m->h;
    const int have_vel = g->vel[0] == g->vel[0] && g->vel[1] == g->vel[1] && g->vel[2] == g->vel[2];
    const int pos = g->lat == g->lat; /* NaN latitude: a velocity-only fix (gnss.vel_delay) */
    const ins_real dtm = (ins_real)(m->t - g->t);
    ins_real z[3], r[3], rm, rn, cm[9], la[3], hr[3][INS_NX];
    int i, mask = 0;
    radii(lat, &rm, &rn);
    ins_dcm_from_quat(m->q, cm);
    mat_vec(cm, e->lever, la); /* C l: the antenna offset, NED */
    if (pos) {
        /* measured - computed antenna position, NED metres (seed 001 eq. 148 in metres), shifted to the step */
        z[0] = (ins_real)(g->lat - m->lat) * (rm + h);
        z[1] = (ins_real)(g->lon - m->lon) * (rn + h) * RCOS(lat);
        z[2] = -(ins_real)(g->h - m->h);
        for (i = 0; i < 3; ++i) z[i] = z[i] - la[i];
        if (!assume_now)
            for (i = 0; i < 3; ++i) z[i] = z[i] + m->v[i] * dtm;
        r[0] = r[1] = sne * sne;
        r[2] = sd * sd;
        if ((int)e->consecutive[INS_GRP_GNSS_POS] >= e->gnss_reset_after) {
            /* GNSS rejected for too long: the INS has drifted; re-initialise position/velocity sigma */
            ins_real sp[3], sv[3];
            for (i = 0; i < 3; ++i) {
                sp[i] = RS(z[i] * z[i] + r[i]);
                sv[i] = (have_vel ? RFABS(g->vel[i] - m->v[i]) : K(0.0)) + K(0.1);
            }
            set_state_sigma(e, 0, sp);
            set_state_sigma(e, 3, sv);
            if (!e->replaying) e->consecutive[INS_GRP_GNSS_VEL] = 0;
        }
        zero_rows(hr, 3);
        ins_gen_H_gnss_pos(cm, e->lever, hr);
        if (apply_rows(c, INS_GRP_GNSS_POS, 3, hr, z, r)) {
            mask |= 1;
            if (g->t > e->t_gnss_ok) e->gnss_dt = g->t - e->t_gnss_ok < 1.0 ? g->t - e->t_gnss_ok : 1.0;
            e->t_gnss_ok = g->t;
            e->h_gnss = g->h + (double)la[2]; /* the IMU height (BaroDatum.gnss_height: C at the fusion) */
            e->gnss_var_d = (double)(sd * sd);
            if (!e->replaying) { /* the hold waits, and would hold here (NoAidHold.gnss) */
                e->t_hold_gnss = g->t;
                e->hold_pos[0] = g->lat;
                e->hold_pos[1] = g->lon;
                e->hold_pos[2] = g->h;
                e->have_hold_pos = 1;
            }
        }
    }
    if (e->use_gnss_vel && have_vel) {
        const ins_real sv = maxr(g->std_vel, e->min_std[2]) * e->std_scale;
        const ins_real *l = e->lever;
        ins_real wl_b[3], wl[3], w[3];
        for (i = 0; i < 3; ++i) w[i] = m->dth_prev[i] / m->dt; /* compensated body rate of the last step */
        wl_b[0] = w[1] * l[2] - w[2] * l[1];
        wl_b[1] = w[2] * l[0] - w[0] * l[2];
        wl_b[2] = w[0] * l[1] - w[1] * l[0];
        ins_dcm_from_quat(m->q, cm); /* after the position feedback */
        mat_vec(cm, wl_b, wl);
        for (i = 0; i < 3; ++i) {
            z[i] = g->vel[i] - (m->v[i] + wl[i]);
            r[i] = sv * sv;
        }
        zero_rows(hr, 3);
        ins_gen_H_gnss_vel(cm, w, l, hr);
        if (apply_rows(c, INS_GRP_GNSS_VEL, 3, hr, z, r)) mask |= 2;
    }
    return mask;
}

/* ZUPT/ZARU at rest and the NHC in motion after each filter step (ins_hil.core_parts.aids.VehicleAids._ground,
 * without lever arm, mounting states or suspension pitch). w_b: this step's compensated body rate. */
static void ground_aids(ins_core_t *c, const ins_real w_b[3]) {
    ins_ekf_t *e = &c->ekf;
    ins_mech_t *m = &c->mech;
    ins_real a, wn, fn, v2, z[3], r[3], hr[3][INS_NX], cm[9], w[3];
    const double t = m->t;
    int i, still;
    if (!e->nhc && !e->zupt) return;
    a = m->dt / e->zupt_tau;
    if (a > K(1.0)) a = K(1.0);
    for (i = 0; i < 3; ++i) {
        e->ema_w[i] = e->ema_w[i] + a * (w_b[i] - e->ema_w[i]);
        e->ema_f[i] = e->ema_f[i] + a * (m->f_ned[i] - e->ema_f[i]);
    }
    wn = RS(e->ema_w[0] * e->ema_w[0] + e->ema_w[1] * e->ema_w[1] + e->ema_w[2] * e->ema_w[2]);
    fn = RS(e->ema_f[0] * e->ema_f[0] + e->ema_f[1] * e->ema_f[1] +
            (e->ema_f[2] + e->g_local) * (e->ema_f[2] + e->g_local));
    v2 = m->v[0] * m->v[0] + m->v[1] * m->v[1] + m->v[2] * m->v[2];
    still = v2 < e->zupt_max_speed * e->zupt_max_speed && wn < e->zupt_gyro && fn < e->zupt_accel;
    e->still_time = still ? e->still_time + (double)m->dt : 0.0;
    if (t < e->nhc_next) return;
    e->nhc_next = t + e->nhc_period;
    zero_rows(hr, 3);
    if (e->zupt && e->still_time >= (double)e->zupt_time) {
        for (i = 0; i < 3; ++i) {
            w[i] = e->ema_w[i];
            z[i] = -m->v[i]; /* 0 - v */
            r[i] = e->zupt_std * e->zupt_std;
        }
        ins_gen_H_zupt(hr);
        if (e->zaru) e->ema_w[0] = e->ema_w[1] = e->ema_w[2] = K(0.0);
        apply_rows(c, INS_GRP_ZUPT, 3, hr, z, r);
        if (e->zaru) { /* zero angular rate: z = 0 - averaged rate */
            zero_rows(hr, 3);
            ins_gen_H_zaru(hr);
            for (i = 0; i < 3; ++i) {
                z[i] = -w[i];
                r[i] = e->zaru_std * e->zaru_std;
            }
            apply_rows(c, INS_GRP_ZUPT, 3, hr, z, r);
        }
        return;
    }
    if (e->nhc && RS(v2) > e->nhc_min_speed) {
        /* v_b,y = v_b,z = 0: z = -(C^T v)_{y,z} */
        ins_dcm_from_quat(m->q, cm);
        for (i = 0; i < 2; ++i) {
            const int row = i + 1; /* row of C^T = column of C */
            z[i] = -(cm[row] * m->v[0] + cm[3 + row] * m->v[1] + cm[6 + row] * m->v[2]);
        }
        ins_gen_H_nhc(cm, m->v, hr);
        r[0] = e->nhc_std * e->nhc_std;
        r[1] = e->nhc_std_vertical * e->nhc_std_vertical;
        apply_rows(c, INS_GRP_NHC, e->nhc_vertical ? 2 : 1, hr, z, r);
    }
}

int ins_core_fuse_baro(ins_core_t *c, double t, ins_pos altitude) {
    ins_ekf_t *e = &c->ekf;
    ins_real z, r, hr[1][INS_NX];
    if (!e->have_baro_offset) { /* baro datum -> ellipsoid: configured, or from the first sample */
        if (!e->baro_offset_fixed) e->baro_offset = c->mech.h - altitude;
        e->baro_offset_var = (double)e->P[2][2];
        e->have_baro_offset = 1;
    } else if (fabs(t - e->t_gnss_ok) < 0.5 && e->baro_offset_tau > 0.0 && !e->baro_offset_fixed) {
        /* calibrate the datum against the GNSS height while GNSS is accepted (first order, tau); each GNSS
         * height is used by the k baro samples until the next one: its error enters k times coherently,
         * the baro noise once per sample (as NavCore._learn_baro_datum) */
        const double dt = t - e->t_baro > 0.0 ? t - e->t_baro : 0.0;
        const double k = dt > 0.0 && e->gnss_dt / dt > 1.0 ? e->gnss_dt / dt : 1.0;
        const double var_in = (double)e->baro_std * (double)e->baro_std + k * e->gnss_var_d;
        double a = dt / e->baro_offset_tau;
        if (a > 1.0) a = 1.0;
        e->baro_offset += a * (e->h_gnss - altitude - e->baro_offset);
        e->baro_offset_var = (1.0 - a) * (1.0 - a) * e->baro_offset_var + a * a * var_in;
        if (dt > 0.0) e->baro_dt = dt;
    }
    e->t_baro = t;
    z = (ins_real)((altitude + e->baro_offset) - c->mech.h); /* h_baro - h = -dr_D (book eq. 3.30) */
    /* a learnt datum's error is common to the samples of its correlation time: it enters R with the variance
     * it has over the 2 tau / dt samples it spans (NavCore's baro fusion) */
    r = e->baro_std * e->baro_std;
    if (!e->baro_offset_fixed) {
        const double n = 2.0 * e->baro_offset_tau / (e->baro_dt > 1e-3 ? e->baro_dt : 1e-3);
        r += (ins_real)(e->baro_offset_var * (n > 1.0 ? n : 1.0));
    }
    zero_rows(hr, 1);
    ins_gen_H_baro(hr);
    return apply_rows(c, INS_GRP_BARO, 1, hr, &z, &r);
}

void ins_core_output(const ins_core_t *c, ins_out_t *o) {
    int i;
    o->t = c->mech.t;
    for (i = 0; i < 4; ++i) o->q[i] = c->mech.q[i];
    for (i = 0; i < 3; ++i) {
        o->v[i] = c->mech.v[i];
        o->bg[i] = c->ekf.bg[i];
        o->ba[i] = c->ekf.ba[i];
        o->std_pos[i] = RS(c->ekf.P[i][i]);
        o->std_vel[i] = RS(c->ekf.P[3 + i][3 + i]);
        o->std_att[i] = RS(c->ekf.P[6 + i][6 + i]);
    }
    o->lat = c->mech.lat;
    o->lon = c->mech.lon;
    o->h = c->mech.h;
}

int ins_core_fuse_mag(ins_core_t *c, double t, const ins_real field_b[3]) {
    /* z = rows 2-3 of tau (m x C mb): m the unit reference, mb the unit measured field (measurements.magnetometer) */
    ins_ekf_t *e = &c->ekf;
    const ins_real *m = e->mag_ref;
    ins_real cm[9], mb[3], cmb[3], x[3], z[2], r[2], hr[2][INS_NX], n, k;
    int i;
    (void)t;
    if (!e->have_mag) return 0;
    n = RS(field_b[0] * field_b[0] + field_b[1] * field_b[1] + field_b[2] * field_b[2]);
    if (!(n > K(0.0))) return 0;
    for (i = 0; i < 3; ++i) mb[i] = field_b[i] / n;
    ins_dcm_from_quat(c->mech.q, cm);
    mat_vec(cm, mb, cmb);
    x[0] = m[1] * cmb[2] - m[2] * cmb[1];
    x[1] = m[2] * cmb[0] - m[0] * cmb[2];
    x[2] = m[0] * cmb[1] - m[1] * cmb[0];
    k = K(1.0) / (K(1.0) + m[0]); /* tau, book eq. 3.33 */
    z[0] = -m[1] * x[0] + (K(1.0) - m[1] * m[1] * k) * x[1] + (-m[1] * m[2] * k) * x[2];
    z[1] = -m[2] * x[0] + (-m[1] * m[2] * k) * x[1] + (K(1.0) - m[2] * m[2] * k) * x[2];
    r[0] = r[1] = e->mag_std * e->mag_std;
    zero_rows(hr, 2);
    ins_gen_H_mag(m, hr);
    return apply_rows(c, INS_GRP_MAG, 2, hr, z, r);
}

/* the no-aid hold after a live step (NoAidHold.due / measurements; not in a replay) */
static void hold(ins_core_t *c) {
    ins_ekf_t *e = &c->ekf;
    ins_mech_t *m = &c->mech;
    const double t = m->t;
    const ins_real lat = (ins_real)m->lat, h = (ins_real)m->h, zero[3] = {0, 0, 0};
    ins_real z[3], zv[3], r[3], rm, rn, cm[9], hr[3][INS_NX];
    int i;
    if (!e->have_hold_pos || t - e->t_hold_gnss < (double)e->hold_after || t - e->t_hold < e->hold_period - 1e-9)
        return;
    e->t_hold = t;
    radii(lat, &rm, &rn);
    z[0] = (ins_real)(e->hold_pos[0] - m->lat) * (rm + h);
    z[1] = (ins_real)(e->hold_pos[1] - m->lon) * (rn + h) * RCOS(lat);
    z[2] = -(ins_real)(e->hold_pos[2] - m->h);
    for (i = 0; i < 3; ++i) {
        z[i] = z[i] - K(0.0);
        zv[i] = -m->v[i];
        r[i] = e->hold_std * e->hold_std;
    }
    ins_dcm_from_quat(m->q, cm);
    zero_rows(hr, 3);
    ins_gen_H_gnss_pos(cm, zero, hr);
    apply_rows(c, INS_GRP_HOLD, 3, hr, z, r);
    if (e->hold_vel_std > K(0.0)) {
        for (i = 0; i < 3; ++i) r[i] = e->hold_vel_std * e->hold_vel_std;
        zero_rows(hr, 3);
        ins_gen_H_zupt(hr);
        apply_rows(c, INS_GRP_HOLD, 3, hr, zv, r);
    }
}

/* ----------------------------------------------------------- delayed fusion (history.py) */

void ins_hist_init(ins_hist_t *h, double max_delay) {
    h->snap_first = h->snap_n = 0;
    /* the ring starts small (its slots stay in cache) and doubles when full, up to INS_HIST_N */
    h->snap_cap = INS_HIST_N;
    while (h->snap_cap % 2 == 0 && h->snap_cap > 64) h->snap_cap /= 2;
    h->meas_first = h->meas_n = 0;
    h->max_delay = max_delay;
    h->rollbacks = h->too_old = 0;
}

/* *dst = *src but for the rows of P past the active states (zero in the core, never read; their bytes in a
 * snapshot slot undefined): the mechanization and P's first nx rows, then the rest of the filter and the core */
static void core_copy(ins_core_t *dst, const ins_core_t *src) {
    const char *s = (const char *)src;
    char *d = (char *)dst;
    const size_t n1 = (size_t)((const char *)&src->ekf.P[src->ekf.nx] - s), n2 = (size_t)((const char *)&src->ekf.x - s);
    memcpy(d, s, n1);
    memcpy(d + n2, s + n2, sizeof(ins_core_t) - n2);
}

static uint32_t snap_idx(const ins_hist_t *h, uint32_t i) { return (h->snap_first + i) % h->snap_cap; }

/* the ring full below INS_HIST_N: twice the slots, the wrapped snapshots moved past the old end (the same ring) */
static void grow_snaps(ins_hist_t *h) {
    const uint32_t cap = h->snap_cap;
    uint32_t i;
    for (i = 0; i < h->snap_n; ++i) {
        const uint32_t from = h->snap_first + i;
        if (from >= cap) {
            core_copy(&h->snap[from], &h->snap[from - cap]);
            h->snap_step[from] = h->snap_step[from - cap];
            h->snap_t[from] = h->snap_t[from - cap];
        }
    }
    h->snap_cap = 2 * cap;
}

static void push_snap(ins_hist_t *h, const ins_core_t *c) {
    uint32_t k;
    if (h->snap_n == h->snap_cap && 2 * h->snap_cap <= INS_HIST_N) grow_snaps(h);
    if (h->snap_n == h->snap_cap) { /* full: the oldest goes */
        h->snap_first = (h->snap_first + 1) % h->snap_cap;
        h->snap_n--;
    }
    k = snap_idx(h, h->snap_n);
    core_copy(&h->snap[k], c);
    h->snap[k].ekf.replaying = 0;
    h->snap_step[k] = c->steps;
    h->snap_t[k] = c->mech.t;
    h->snap_n++;
}

static void log_meas(ins_hist_t *h, const ins_hmeas_t *m) {
    if (h->meas_n == INS_HIST_MEAS) {
        h->meas_first = (h->meas_first + 1) % INS_HIST_MEAS;
        h->meas_n--;
    }
    h->meas[(h->meas_first + h->meas_n) % INS_HIST_MEAS] = *m;
    h->meas_n++;
}

void ins_hist_step(ins_hist_t *h, ins_core_t *c, const ins_real dth[3], const ins_real dv[3], double t_end,
                   ins_real dt) {
    const uint32_t k = c->steps % INS_HIST_N;
    double horizon;
    int i;
    for (i = 0; i < 3; ++i) {
        h->imu[k][i] = dth[i];
        h->imu[k][3 + i] = dv[i];
    }
    h->imu[k][6] = dt;
    h->imu_t[k] = t_end;
    if (dt > K(0.0)) ins_core_step_dt(c, dth, dv, t_end, dt);
    else ins_core_step(c, dth, dv, t_end);
    push_snap(h, c);
    horizon = c->mech.t - h->max_delay - 2.0 * (double)c->mech.dt;
    while (h->snap_n > 0 && h->snap_t[h->snap_first] < horizon) {
        h->snap_first = (h->snap_first + 1) % h->snap_cap;
        h->snap_n--;
    }
    {
        const uint32_t first = h->snap_n > 0 ? h->snap_step[h->snap_first] : c->steps;
        while (h->meas_n > 0 && h->meas[h->meas_first].step < first) {
            h->meas_first = (h->meas_first + 1) % INS_HIST_MEAS;
            h->meas_n--;
        }
    }
}

static int fuse_now(ins_core_t *c, const ins_hmeas_t *m, int assume_now) {
    if (m->kind == 0) return ins_core_fuse_gnss_at(c, &m->g, assume_now);
    if (m->kind == 2) return ins_core_fuse_mag(c, m->t, m->field);
    return ins_core_fuse_baro(c, m->t, m->alt);
}

/* A measurement valid at tm rolls the history back (1; *ti: the snapshot it is fused at), or is fused now (0; *late:
 * it is older than the history, NavCore fuses it now) */
static int hist_target(const ins_hist_t *h, const ins_core_t *c, double tm, uint32_t *ti, int *late) {
    const double dt = (double)c->mech.dt;
    uint32_t i;
    *late = 0;
    if (!(tm < c->mech.t - 0.5 * dt && h->max_delay > 0.0)) return 0;
    *late = 1;
    for (i = h->snap_n; i-- > 0;)
        if (h->snap_t[snap_idx(h, i)] <= tm + 0.5 * dt) {
            *ti = i;
            return c->steps - h->snap_step[snap_idx(h, i)] < INS_HIST_N;
        }
    return 0;
}

/* NavCore._fuse_one + DelayedHistory.fuse_delayed_steps (in one piece) */
static int hist_fuse(ins_hist_t *h, ins_core_t *c, ins_hmeas_t *m) {
    const double dt = (double)c->mech.dt, t_now = c->mech.t;
    const double tm = m->t;
    uint32_t ti = 0;
    int r, late;
    if (hist_target(h, c, tm, &ti, &late)) {
        uint32_t cur = c->steps, ts, k, j, n, ord[INS_HIST_MEAS];
        /* counters and the last test ratios are the live ones (not part of NavCore's snapshot) */
        uint32_t acc[INS_NGRP], rej[INS_NGRP], con[INS_NGRP];
        ins_real lr[INS_NGRP];
        double hp[3], tg = c->ekf.t_hold_gnss, th = c->ekf.t_hold;
        const int hh = c->ekf.have_hold_pos;
        struct ins_out_s *const pub = c->pub; /* the caller's publication target: not filter state */
        for (k = 0; k < 3; ++k) hp[k] = c->ekf.hold_pos[k];
        for (k = 0; k < INS_NGRP; ++k) {
            acc[k] = c->ekf.accepted[k];
            rej[k] = c->ekf.rejected[k];
            con[k] = c->ekf.consecutive[k];
            lr[k] = c->ekf.last_ratio[k];
        }
        ts = h->snap_step[snap_idx(h, ti)];
        core_copy(c, &h->snap[snap_idx(h, ti)]);
        c->pub = pub; /* (a snapshot taken before the caller set it holds NULL) */
        for (k = 0; k < INS_NGRP; ++k) {
            c->ekf.accepted[k] = acc[k];
            c->ekf.rejected[k] = rej[k];
            c->ekf.consecutive[k] = con[k];
            c->ekf.last_ratio[k] = lr[k];
        }
        for (k = 0; k < 3; ++k) c->ekf.hold_pos[k] = hp[k]; /* the hold's state is live (NoAidHold) */
        c->ekf.t_hold_gnss = tg;
        c->ekf.t_hold = th;
        c->ekf.have_hold_pos = hh;
        c->ekf.replaying = 0;
        r = fuse_now(c, m, 0); /* counted and gated like any measurement */
        c->ekf.replaying = 1;
        h->snap_n = ti + 1; /* the snapshots after the target are replayed; the target's is this state */
        core_copy(&h->snap[snap_idx(h, ti)], c);
        h->snap[snap_idx(h, ti)].ekf.replaying = 0;
        /* replay in the order things happened: the measurements fused at state k (in their order),
         * then the IMU sample that takes state k to k + 1 */
        for (j = 0, n = 0; j < h->meas_n; ++j) { /* the logged measurements from step ts on, by step, in their order */
            uint32_t q = (h->meas_first + j) % INS_HIST_MEAS, i = n++;
            if (h->meas[q].step < ts) {
                n--;
                continue;
            }
            for (; i > 0 && h->meas[ord[i - 1]].step > h->meas[q].step; --i) ord[i] = ord[i - 1];
            ord[i] = q;
        }
        for (k = ts, j = 0; k <= cur; ++k) {
            for (; j < n && h->meas[ord[j]].step == k; ++j) fuse_now(c, &h->meas[ord[j]], 0);
            if (k < cur) {
                const uint32_t q = k % INS_HIST_N;
                if (h->imu[q][6] > K(0.0)) ins_core_step_dt(c, h->imu[q], h->imu[q] + 3, h->imu_t[q], h->imu[q][6]);
                else ins_core_step(c, h->imu[q], h->imu[q] + 3, h->imu_t[q]);
                push_snap(h, c);
            }
        }
        c->ekf.replaying = 0;
        m->step = ts;
        log_meas(h, m);
        h->rollbacks++;
        return r;
    }
    if (late) h->too_old++;
    m->step = c->steps;
    r = fuse_now(c, m, tm < t_now - 1.5 * dt);
    if (h->max_delay > 0.0) log_meas(h, m);
    return r;
}

int ins_hist_fuse_gnss(ins_hist_t *h, ins_core_t *c, const ins_gnss_t *g) {
    ins_hmeas_t m;
    m.kind = 0;
    m.g = *g;
    m.t = g->t;
    m.alt = 0.0;
    m.field[0] = m.field[1] = m.field[2] = K(0.0);
    return hist_fuse(h, c, &m);
}

/* the position g of a fix whose velocity, valid at t_vel, is fused next (ins_hist_fuse_gnss_split) */
static int hist_fuse_gnss_before(ins_hist_t *h, ins_core_t *c, const ins_gnss_t *g, double t_vel) {
    uint32_t ti;
    int late, r;
    if (hist_target(h, c, g->t, &ti, &late) || late || !hist_target(h, c, t_vel, &ti, &late))
        return ins_hist_fuse_gnss(h, c, g);
    /* the roll-back of the velocity restores a snapshot of this step or before and replays this position: only what
     * outlives it now (the gate, its counters and ratio, the hold's position; the log entry) */
    c->ekf.gate_only = 1;
    r = ins_hist_fuse_gnss(h, c, g);
    c->ekf.gate_only = 0;
    return r;
}

int ins_hist_fuse_gnss_split(ins_hist_t *h, ins_core_t *c, const ins_gnss_t *pos, const ins_gnss_t *vel, int *r_pos,
                             void (*after_pos)(void *ctx, const ins_core_t *c), void *ctx) {
    *r_pos = hist_fuse_gnss_before(h, c, pos, vel->t);
    if (after_pos != NULL) after_pos(ctx, c);
    return ins_hist_fuse_gnss(h, c, vel);
}

int ins_hist_fuse_mag(ins_hist_t *h, ins_core_t *c, double t, const ins_real field_b[3]) {
    ins_hmeas_t m;
    int i;
    m.kind = 2;
    m.g.t = t;
    m.t = t;
    m.alt = 0.0;
    for (i = 0; i < 3; ++i) m.field[i] = field_b[i];
    return hist_fuse(h, c, &m);
}

int ins_hist_fuse_baro(ins_hist_t *h, ins_core_t *c, double t, ins_pos altitude) {
    ins_hmeas_t m;
    m.kind = 1;
    m.g.t = t;
    m.t = t;
    m.alt = altitude;
    m.field[0] = m.field[1] = m.field[2] = K(0.0);
    return hist_fuse(h, c, &m);
}
