/* Glue for the Python extension only (compiled by firmware_ref/cffi_build.py, not by the Makefile):
 * double-precision entry points for both scalar builds, and a flat state record. */
#include <math.h>

#include "ins_ref.h"
int cref_scalar_bits(void) { return INS_REF_SCALAR_BITS; }
void cref_init(ins_core_t *c, const double q[4], const double v[3], double lat, double lon, double h, double t,
               double dt, const ins_ekf_cfg_t *cfg, int filter) {
    ins_real qq[4], vv[3];
    int i;
    for (i = 0; i < 4; ++i) qq[i] = (ins_real)q[i];
    for (i = 0; i < 3; ++i) vv[i] = (ins_real)v[i];
    ins_core_init(c, qq, vv, lat, lon, h, t, (ins_real)dt, cfg, filter);
}
/* one step (dt > 0: of its own length, else the fixed step); through the delayed-fusion history h if not NULL */
void cref_hstep(ins_core_t *c, ins_hist_t *h, const double dth[3], const double dv[3], double t_end, double dt) {
#ifdef INS_REF_FLOAT
    ins_real a[3], u[3];
    int i;
    for (i = 0; i < 3; ++i) { a[i] = (ins_real)dth[i]; u[i] = (ins_real)dv[i]; }
#else
    const ins_real *a = dth, *u = dv;
#endif
    if (h != NULL) ins_hist_step(h, c, a, u, t_end, (ins_real)dt);
    else if (dt > 0.0) ins_core_step_dt(c, a, u, t_end, (ins_real)dt);
    else ins_core_step(c, a, u, t_end);
}
void cref_step(ins_core_t *c, const double dth[3], const double dv[3], double t_end) {
    cref_hstep(c, NULL, dth, dv, t_end, 0.0);
}
void cref_hist_init(ins_hist_t *h, double max_delay) { ins_hist_init(h, max_delay); }
/* t, q[4], v[3], lat, lon, h, bg[3], ba[3], std_pos[3], std_vel[3], std_att[3], omega_b[3], f_b[3] (32 values);
 * omega_b, f_b: the last bias-compensated increments / dt (rad/s, m/s^2, body) */
static void put_out(const ins_core_t *c, const ins_out_t *rp, double *o, size_t n) {
    const ins_out_t r = *rp;
    double all[32];
    size_t i;
    all[0] = r.t;
    for (i = 0; i < 4; ++i) all[1 + i] = (double)r.q[i];
    for (i = 0; i < 3; ++i) {
        all[5 + i] = (double)r.v[i];
        all[11 + i] = (double)r.bg[i];
        all[14 + i] = (double)r.ba[i];
        all[17 + i] = (double)r.std_pos[i];
        all[20 + i] = (double)r.std_vel[i];
        all[23 + i] = (double)r.std_att[i];
        all[26 + i] = (double)(c->mech.dth_prev[i] / c->mech.dt);
        all[29 + i] = (double)(c->mech.dv_prev[i] / c->mech.dt);
    }
    all[8] = r.lat; all[9] = r.lon; all[10] = r.h;
    for (i = 0; i < n; ++i) o[i] = all[i];
}
static void put(const ins_core_t *c, double *o, size_t n) {
    ins_out_t r;
    ins_core_output(c, &r);
    put_out(c, &r, o, n);
}
void cref_state(const ins_core_t *c, double out[32]) { put(c, out, 32); }
/* the state the last step published after its mechanization (c->pub; as cref_state) */
void cref_pub_state(const ins_core_t *c, double out[32]) { put_out(c, c->pub, out, 32); }
/* n steps in one call (dts: each step's length, or NULL: the fixed step); out (or NULL): n records of out_stride
 * values, per step the state after the step (pub = 0, as cref_state) or the state the step published after its
 * mechanization (pub != 0: c->pub, as cref_pub_state after cref_hstep, CNavCore.step_begin; c->pub must be set) */
void cref_run(ins_core_t *c, ins_hist_t *h, const double *inc, const double *t_end, const double *dts, size_t n,
              double *out, size_t out_stride, int pub) {
    size_t k;
    for (k = 0; k < n; ++k) {
        cref_hstep(c, h, inc + 6 * k, inc + 6 * k + 3, t_end != NULL ? t_end[k] : c->mech.t + (double)c->mech.dt,
                   dts != NULL ? dts[k] : 0.0);
        if (out == NULL) continue;
        if (pub) put_out(c, c->pub, out + out_stride * k, out_stride);
        else put(c, out + out_stride * k, out_stride);
    }
}
/* the pipeline's core guard (ins_hil.runtime.pipeline.state_ok) on n state records of stride values (cref_state's
 * layout: t, q[4], v[3], lat, lon, h, b_g[3], b_a[3], sigma pos[3], vel[3], att[3]): the index of the first that fails
 * (n: none). The same comparisons in the same order (NaN fails each): |q|^2 - 1 within qtol, |v|^2 < vmax2,
 * |lat| <= pi/2, |lon| < 1e3, hmin < h < hmax, every sigma in [0, inf) */
size_t cref_guard(const double *rows, size_t n, size_t stride, double qtol, double vmax2, double hmin, double hmax) {
    size_t k;
    int i;
    if (stride < 26) return 0; /* not state records: the first fails */
    for (k = 0; k < n; ++k) {
        const double *r = rows + stride * k;
        int ok = fabs(r[1] * r[1] + r[2] * r[2] + r[3] * r[3] + r[4] * r[4] - 1.0) < qtol
                 && r[5] * r[5] + r[6] * r[6] + r[7] * r[7] < vmax2
                 && -1.5707963267948966 <= r[8] && r[8] <= 1.5707963267948966
                 && -1e3 < r[9] && r[9] < 1e3
                 && hmin < r[10] && r[10] < hmax;
        for (i = 17; ok && i < 26; ++i) ok = 0.0 <= r[i] && r[i] < HUGE_VAL;
        if (!ok) return k;
    }
    return n;
}
/* the GNSS fix of the glue's arguments */
static ins_gnss_t gnss_of(double t, double lat, double lon, double h, const double vel[3], double std_ne, double std_d,
                          double std_vel) {
    ins_gnss_t g;
    int i;
    g.t = t; g.lat = lat; g.lon = lon; g.h = h;
    for (i = 0; i < 3; ++i) g.vel[i] = (ins_real)vel[i];
    g.std_ne = (ins_real)std_ne; g.std_d = (ins_real)std_d; g.std_vel = (ins_real)std_vel;
    return g;
}
int cref_hfuse_gnss(ins_core_t *c, ins_hist_t *hs, double t, double lat, double lon, double h, const double vel[3],
                    double std_ne, double std_d, double std_vel) {
    const ins_gnss_t g = gnss_of(t, lat, lon, h, vel, std_ne, std_d, std_vel);
    return hs != NULL ? ins_hist_fuse_gnss(hs, c, &g) : ins_core_fuse_gnss(c, &g);
}
int cref_fuse_gnss(ins_core_t *c, double t, double lat, double lon, double h, const double vel[3], double std_ne,
                   double std_d, double std_vel) {
    return cref_hfuse_gnss(c, NULL, t, lat, lon, h, vel, std_ne, std_d, std_vel);
}
int cref_hfuse_baro(ins_core_t *c, ins_hist_t *hs, double t, double altitude) {
    return hs != NULL ? ins_hist_fuse_baro(hs, c, t, altitude) : ins_core_fuse_baro(c, t, altitude);
}
int cref_fuse_baro(ins_core_t *c, double t, double altitude) { return ins_core_fuse_baro(c, t, altitude); }
/* n GNSS updates in one call (benchmark of the update path); returns the number fully accepted */
int cref_fuse_gnss_repeat(ins_core_t *c, double lat, double lon, double h, const double vel[3], double std_ne,
                          double std_d, double std_vel, size_t n) {
    size_t k;
    int acc = 0;
    for (k = 0; k < n; ++k) acc += cref_fuse_gnss(c, c->mech.t, lat, lon, h, vel, std_ne, std_d, std_vel) == 3;
    return acc;
}
int cref_hfuse_mag(ins_core_t *c, ins_hist_t *hs, double t, const double field[3]) {
    ins_real f[3];
    int i;
    for (i = 0; i < 3; ++i) f[i] = (ins_real)field[i];
    return hs != NULL ? ins_hist_fuse_mag(hs, c, t, f) : ins_core_fuse_mag(c, t, f);
}
/* the GNSS-velocity yaw bank (ins_gsf_t) in double for both builds */
void cref_gsf_predict(ins_gsf_t *g, const double dth[3], const double dv[3], double dt, double forward_speed) {
    ins_real a[3], u[3];
    int i;
    for (i = 0; i < 3; ++i) { a[i] = (ins_real)dth[i]; u[i] = (ins_real)dv[i]; }
    ins_gsf_predict(g, a, u, (ins_real)dt, (ins_real)forward_speed);
}
void cref_gsf_fuse_vel(ins_gsf_t *g, const double vel_ne[2], double std) {
    ins_real v[2];
    v[0] = (ins_real)vel_ne[0];
    v[1] = (ins_real)vel_ne[1];
    ins_gsf_fuse_vel(g, v, (ins_real)std);
}
/* the mechanization of the alignment's heading phase (CNavCore before the hand-over) from NavCore's StrapdownNED */
void cref_mech_set(ins_mech_t *m, const double q[4], const double v[3], double lat, double lon, double h, double t,
                   const double dth_prev[3], const double dv_prev[3], int have_prev) {
    ins_real qq[4], vv[3];
    int i;
    for (i = 0; i < 4; ++i) qq[i] = (ins_real)q[i];
    for (i = 0; i < 3; ++i) vv[i] = (ins_real)v[i];
    ins_mech_init(m, qq, vv, lat, lon, h, t, (ins_real)0.01);
    for (i = 0; i < 3; ++i) {
        m->dth_prev[i] = (ins_real)dth_prev[i];
        m->dv_prev[i] = (ins_real)dv_prev[i];
    }
    m->have_prev = have_prev;
}
/* n heading-phase steps (ins_align_heading_step; g may be NULL); out: per step t, q[4], lat, lon, h, omega_b[3] */
void cref_heading_run(ins_mech_t *m, ins_gsf_t *g, const double *inc, const double *t_end, const double *dts, size_t n,
                      const double bg[3], const double ba[3], double *out) {
    ins_real b[3], c[3], a[3], u[3], w[3];
    size_t k;
    int i;
    for (i = 0; i < 3; ++i) {
        b[i] = (ins_real)bg[i];
        c[i] = (ins_real)ba[i];
    }
    for (k = 0; k < n; ++k) {
        double *o = out + 11 * k;
        for (i = 0; i < 3; ++i) {
            a[i] = (ins_real)inc[6 * k + (size_t)i];
            u[i] = (ins_real)inc[6 * k + 3 + (size_t)i];
        }
        ins_align_heading_step(m, g, a, u, (ins_real)dts[k], t_end[k], b, c, w);
        o[0] = m->t;
        for (i = 0; i < 4; ++i) o[1 + i] = (double)m->q[i];
        o[5] = m->lat; o[6] = m->lon; o[7] = m->h;
        for (i = 0; i < 3; ++i) o[8 + i] = (double)w[i];
    }
}
/* the static alignment's levelling window and start-up check (align.c), in double for both builds */
int cref_level_step(ins_level_t *l, const double dth[3], const double dv[3], double dt, double t) {
    ins_real a[3], u[3];
    int i;
    for (i = 0; i < 3; ++i) { a[i] = (ins_real)dth[i]; u[i] = (ins_real)dv[i]; }
    return ins_level_step(l, a, u, dt, t);
}
int cref_imu_check_add(ins_imu_check_t *c, const double dth[3], const double dv[3], double dt) {
    ins_real a[3], u[3];
    int i;
    for (i = 0; i < 3; ++i) { a[i] = (ins_real)dth[i]; u[i] = (ins_real)dv[i]; }
    return ins_imu_check_add(c, a, u, dt);
}
#define CREF_LEVEL_CHECKED 4 /* the start-up check is full at this sample (judge it) */
#define CREF_LEVEL_BAD 8     /* a sample with a non-finite value or dt <= 0: not taken (NavCore's check_imu refuses it) */
/* the levelling window's state but its ring (a sample's step undone) */
typedef struct {
    uint32_t first, n_win, n_pend;
    ins_real f_sum[3], w_sum[3];
    double t_win, dev_w, dev_f;
    int moving, imu_moving;
} level_scalars_t;
static void level_save(const ins_level_t *l, level_scalars_t *s) {
    int i;
    s->first = l->first; s->n_win = l->n_win; s->n_pend = l->n_pend;
    for (i = 0; i < 3; ++i) { s->f_sum[i] = l->f_sum[i]; s->w_sum[i] = l->w_sum[i]; }
    s->t_win = l->t_win; s->dev_w = l->dev_w; s->dev_f = l->dev_f;
    s->moving = l->moving; s->imu_moving = l->imu_moving;
}
static void level_restore(ins_level_t *l, const level_scalars_t *s) {
    int i;
    l->first = s->first; l->n_win = s->n_win; l->n_pend = s->n_pend;
    for (i = 0; i < 3; ++i) { l->f_sum[i] = s->f_sum[i]; l->w_sum[i] = s->w_sum[i]; }
    l->t_win = s->t_win; l->dev_w = s->dev_w; l->dev_f = s->dev_f;
    l->moving = s->moving; l->imu_moving = s->imu_moving;
}
/* n samples of the levelling phase as NavCore.step takes them: per sample the levelling window, the start-up check
 * (chk; NULL once it has judged) and the yaw bank (g or NULL) with dtheta - bg dt and the raw dvel (independent of
 * each other: NavCore's order is check, bank, window). Stops after the sample at which the check is full, and before
 * a sample at which the levelling is due (INS_LEVEL_DUE: its window step undone, so the caller levels with it one
 * sample at a time), that is bad, or that the ring cannot take. Returns those flags (0: all n taken) and the samples
 * taken in *done. */
int cref_level_run(ins_level_t *l, ins_imu_check_t *chk, ins_gsf_t *g, const double bg[3], const double *inc,
                   const double *t_end, const double *dts, size_t n, size_t *done) {
    const double inf = (double)INFINITY;
    level_scalars_t was;
    ins_real a[3], u[3], c[3];
    size_t k;
    int i, r;
    for (k = 0; k < n; ++k) {
        const double *x = inc + 6 * k, dt = dts[k], t = t_end[k];
        if (!(0.0 < dt && dt < inf && fabs(t) < inf && fabs(x[0]) < inf && fabs(x[1]) < inf && fabs(x[2]) < inf &&
              fabs(x[3]) < inf && fabs(x[4]) < inf && fabs(x[5]) < inf)) {
            *done = k;
            return CREF_LEVEL_BAD;
        }
        if (l->n_win + l->n_pend >= (uint32_t)INS_LEVEL_N) {
            *done = k;
            return INS_LEVEL_FULL;
        }
        for (i = 0; i < 3; ++i) { a[i] = (ins_real)x[i]; u[i] = (ins_real)x[3 + i]; }
        level_save(l, &was);
        if (ins_level_step(l, a, u, dt, t) == INS_LEVEL_DUE) {
            level_restore(l, &was); /* the ring slot it wrote is beyond the restored count: unused */
            *done = k;
            return INS_LEVEL_DUE;
        }
        r = 0;
        if (chk != NULL && ins_imu_check_add(chk, a, u, dt)) r |= CREF_LEVEL_CHECKED;
        if (g != NULL) {
            for (i = 0; i < 3; ++i) c[i] = (ins_real)(x[i] - bg[i] * dt);
            ins_gsf_predict(g, c, u, (ins_real)dt, (ins_real)0.0);
        }
        if (r != 0) {
            *done = k + 1;
            return r;
        }
    }
    *done = n;
    return 0;
}
/* the held-back samples (the ring's after the window) through the heading step with the gyro bias bg (no yaw bank,
 * no accelerometer bias): Alignment._bring_forward on m (set from NavCore's StrapdownNED by cref_mech_set) */
void cref_level_bring_forward(const ins_level_t *l, ins_mech_t *m, const double bg[3]) {
    ins_real b[3], z[3] = {(ins_real)0.0, (ins_real)0.0, (ins_real)0.0}, w[3];
    uint32_t j, k;
    int i;
    for (i = 0; i < 3; ++i) b[i] = (ins_real)bg[i];
    for (j = 0; j < l->n_pend; ++j) {
        k = (l->first + l->n_win + j) % (uint32_t)INS_LEVEL_N;
        ins_align_heading_step(m, NULL, l->dth[k], l->dv[k], (ins_real)l->dt[k], l->t[k], b, z, w);
    }
}
/* the gate counters of group g after an update against those before it (rej, con): o[0] its test ratio, o[1] 1 if it
 * was rejected, o[2] its rejections in a row before the update, o[3] after it (CNavCore's events and ratios) */
static void gate_info(const ins_ekf_t *e, int g, const uint32_t rej[INS_NGRP], const uint32_t con[INS_NGRP],
                      double o[4]) {
    o[0] = (double)e->last_ratio[g];
    o[1] = e->rejected[g] > rej[g] ? 1.0 : 0.0;
    o[2] = (double)con[g];
    o[3] = (double)e->consecutive[g];
}
static void gate_before(const ins_ekf_t *e, uint32_t rej[INS_NGRP], uint32_t con[INS_NGRP]) {
    int g;
    for (g = 0; g < INS_NGRP; ++g) {
        rej[g] = e->rejected[g];
        con[g] = e->consecutive[g];
    }
}
/* g through the history or the core, its gates in o[0..3] (position) and o[4..7] (velocity) (gate_info) */
static int gfuse_gnss(ins_core_t *c, ins_hist_t *hs, const ins_gnss_t *g, double o[8]) {
    uint32_t rej[INS_NGRP], con[INS_NGRP];
    int r;
    gate_before(&c->ekf, rej, con);
    r = hs != NULL ? ins_hist_fuse_gnss(hs, c, g) : ins_core_fuse_gnss(c, g);
    gate_info(&c->ekf, INS_GRP_GNSS_POS, rej, con, o);
    gate_info(&c->ekf, INS_GRP_GNSS_VEL, rej, con, o + 4);
    return r;
}
/* cref_hfuse_gnss with the velocity as three values (NaN: none) and the gates of the position and the velocity in
 * o[0..3] and o[4..7] (gate_info) */
int cref_gfuse_gnss(ins_core_t *c, ins_hist_t *hs, double t, double lat, double lon, double h, double vn, double ve,
                    double vd, double std_ne, double std_d, double std_vel, double o[8]) {
    double v[3];
    ins_gnss_t g;
    v[0] = vn; v[1] = ve; v[2] = vd;
    g = gnss_of(t, lat, lon, h, v, std_ne, std_d, std_vel);
    return gfuse_gnss(c, hs, &g, o);
}
/* cref_hfuse_baro with its gate in o[0..3] (gate_info) */
int cref_gfuse_baro(ins_core_t *c, ins_hist_t *hs, double t, double altitude, double o[4]) {
    uint32_t rej[INS_NGRP], con[INS_NGRP];
    int r;
    gate_before(&c->ekf, rej, con);
    r = cref_hfuse_baro(c, hs, t, altitude);
    gate_info(&c->ekf, INS_GRP_BARO, rej, con, o);
    return r;
}
/* cref_hfuse_mag with the field as three values and its gate in o[0..3] (gate_info) */
int cref_gfuse_mag(ins_core_t *c, ins_hist_t *hs, double t, double fx, double fy, double fz, double o[4]) {
    uint32_t rej[INS_NGRP], con[INS_NGRP];
    double f[3];
    int r;
    f[0] = fx; f[1] = fy; f[2] = fz;
    gate_before(&c->ekf, rej, con);
    r = cref_hfuse_mag(c, hs, t, f);
    gate_info(&c->ekf, INS_GRP_MAG, rej, con, o);
    return r;
}
/* the gates of a split fix's position (ins_hist_fuse_gnss_split's after_pos): o[0..3] (and o[4..7], unused), then
 * the counters before the velocity */
typedef struct {
    double *o;
    uint32_t rej[INS_NGRP], con[INS_NGRP];
} split_gates_t;
static void split_after_pos(void *ctx, const ins_core_t *c) {
    split_gates_t *x = (split_gates_t *)ctx;
    gate_info(&c->ekf, INS_GRP_GNSS_POS, x->rej, x->con, x->o);
    gate_info(&c->ekf, INS_GRP_GNSS_VEL, x->rej, x->con, x->o + 4);
    gate_before(&c->ekf, x->rej, x->con);
}
/* a GNSS fix with gnss.vel_delay (> 0): its position at t (no velocity), then its velocity at t - vel_delay (no
 * position), as two cref_gfuse_gnss calls: o[0..3] the position's gate, o[4..7] the velocity's; through the history,
 * one ins_hist_fuse_gnss_split (the position's update left to the velocity's roll-back: the same numbers) */
int cref_gfuse_gnss_split(ins_core_t *c, ins_hist_t *hs, double t, double vel_delay, double lat, double lon, double h,
                          double vn, double ve, double vd, double std_ne, double std_d, double std_vel, double o[8]) {
    const double nan = (double)NAN;
    double ov[8], nv[3], v[3];
    int r, i;
    nv[0] = nv[1] = nv[2] = nan;
    if (hs != NULL) {
        split_gates_t x;
        int rp;
        const ins_gnss_t gp = gnss_of(t, lat, lon, h, nv, std_ne, std_d, std_vel);
        ins_gnss_t gv;
        v[0] = vn; v[1] = ve; v[2] = vd;
        gv = gnss_of(t - vel_delay, nan, lon, h, v, std_ne, std_d, std_vel);
        x.o = o;
        gate_before(&c->ekf, x.rej, x.con);
        r = ins_hist_fuse_gnss_split(hs, c, &gp, &gv, &rp, split_after_pos, &x);
        gate_info(&c->ekf, INS_GRP_GNSS_VEL, x.rej, x.con, o + 4);
        return rp | r;
    }
    r = cref_gfuse_gnss(c, hs, t, lat, lon, h, nan, nan, nan, std_ne, std_d, std_vel, o);
    r |= cref_gfuse_gnss(c, hs, t - vel_delay, nan, lon, h, vn, ve, vd, std_ne, std_d, std_vel, ov);
    for (i = 4; i < 8; ++i) o[i] = ov[i];
    return r;
}
/* An offline replay's IMU runs and baro updates alternately, in one call (CNavCore.run_baro). Group g < ng: the IMU
 * samples [end[g - 1], end[g]) (end[-1] = k0; inc, t_end, dts indexed as cref_run's from 0) stepped as cref_run with
 * pub != 0 (c->pub must be set), their records written to out (32 values each, from out[0] for sample k0), then the
 * baro updates [ab[g], ab[g + 1]) (times bt, altitudes alt) through the roll-back history hs as cref_gfuse_baro, each
 * gate into gate (4 per update) and, before it, the time and the yaw sigma of the state it is fused into into pre
 * (2 per update: cref_state's values 0 and 25). The guard is cref_guard's with the bounds given. The call stops after
 * the first group whose run gives a record that fails the guard (its updates not run: *why = 1), or after the first
 * update whose gate is not a plain acceptance (rejected, or accepted after rejections: *why = 2) or whose state then
 * fails the guard (*why = 3); else *why = 0. Returns the updates run; *groups: the groups whose run ran. */
size_t cref_run_baro(ins_core_t *c, ins_hist_t *hs, const double *inc, const double *t_end, const double *dts,
                     size_t k0, const int64_t *end, const int64_t *ab, size_t ng, const double *bt, const double *alt,
                     double *out, double *pre, double *gate, double qtol, double vmax2, double hmin, double hmax,
                     size_t *groups, int *why) {
    size_t g, k = k0, u = 0, a0;
    double rec[32];
    *why = 0;
    for (g = 0; g < ng; ++g) {
        size_t k1 = (size_t)end[g], a1 = (size_t)ab[g + 1];
        cref_run(c, hs, inc + 6 * k, t_end + k, dts + k, k1 - k, out + 32 * (k - k0), 32, 1);
        if (cref_guard(out + 32 * (k - k0), k1 - k, 32, qtol, vmax2, hmin, hmax) != k1 - k) {
            *groups = g + 1;
            *why = 1;
            return u;
        }
        k = k1;
        for (a0 = (size_t)ab[g]; a0 < a1; ++a0, ++u) {
            double *o = gate + 4 * u;
            put(c, rec, 32);
            pre[2 * u] = rec[0];
            pre[2 * u + 1] = rec[25];
            cref_gfuse_baro(c, hs, bt[a0], alt[a0], o);
            if (o[1] != 0.0 || o[2] != 0.0) *why = 2;
            put(c, rec, 32);
            if (cref_guard(rec, 1, 32, qtol, vmax2, hmin, hmax) != 1) *why = 3;
            if (*why) {
                *groups = g + 1;
                return u + 1;
            }
        }
    }
    *groups = ng;
    return u;
}
/* An offline replay's IMU runs and GNSS fixes alternately, in one call (CNavCore.run_gnss; as cref_run_baro). Group
 * g < ng: the IMU samples [end[g - 1], end[g]) (end[-1] = k0) stepped as cref_run with pub != 0 (c->pub must be set),
 * their records written to out (32 values each, from out[0] for sample k0), then the fixes [ab[g], ab[g + 1]) of fix
 * (10 values each: t, lat (NaN: no position), lon, h, vn, ve, vd (NaN: no velocity), std_ne, std_d, std_vel) through
 * the roll-back history hs as CNavCore.fuse does: with vel_delay > 0 and a velocity, cref_gfuse_gnss_split, else
 * cref_gfuse_gnss; each fix's gates into gate (8 per fix: o[0..3] the position's, o[4..7] the velocity's) and, before
 * it, the time and the yaw sigma of the state it is fused into into pre (2 per fix). The call stops after the first
 * group whose run gives a record that fails the guard (its fixes not run: *why = 1), or after the first fix whose
 * position gate (a position given) or velocity gate (a velocity given and check_vel) is not a plain acceptance
 * (rejected, or accepted after rejections: *why = 2) or whose state then fails the guard (*why = 3); else *why = 0.
 * out == NULL: no records, no pre and no guard (the runs as cref_run without output; *why 0 or 2). Returns the fixes
 * run; *groups: the groups whose run ran. */
size_t cref_run_gnss(ins_core_t *c, ins_hist_t *hs, const double *inc, const double *t_end, const double *dts,
                     size_t k0, const int64_t *end, const int64_t *ab, size_t ng, const double *fix, double vel_delay,
                     int check_vel, double *out, double *pre, double *gate, double qtol, double vmax2, double hmin,
                     double hmax, size_t *groups, int *why) {
    size_t g, k = k0, u = 0, a0;
    double rec[32];
    *why = 0;
    for (g = 0; g < ng; ++g) {
        size_t k1 = (size_t)end[g], a1 = (size_t)ab[g + 1];
        if (out == NULL) {
            cref_run(c, hs, inc + 6 * k, t_end + k, dts + k, k1 - k, NULL, 0, 0);
        } else {
            cref_run(c, hs, inc + 6 * k, t_end + k, dts + k, k1 - k, out + 32 * (k - k0), 32, 1);
            if (cref_guard(out + 32 * (k - k0), k1 - k, 32, qtol, vmax2, hmin, hmax) != k1 - k) {
                *groups = g + 1;
                *why = 1;
                return u;
            }
        }
        k = k1;
        for (a0 = (size_t)ab[g]; a0 < a1; ++a0, ++u) {
            const double *f = fix + 10 * a0;
            double *o = gate + 8 * u;
            const int has_pos = f[1] == f[1], has_vel = f[4] == f[4];
            if (out != NULL) {
                put(c, rec, 32);
                pre[2 * u] = rec[0];
                pre[2 * u + 1] = rec[25];
            }
            if (has_vel && vel_delay > 0.0)
                cref_gfuse_gnss_split(c, hs, f[0], vel_delay, f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8], f[9], o);
            else
                cref_gfuse_gnss(c, hs, f[0], f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8], f[9], o);
            if ((has_pos && (o[1] != 0.0 || o[2] != 0.0)) || (has_vel && check_vel && (o[5] != 0.0 || o[6] != 0.0)))
                *why = 2;
            if (out != NULL) {
                put(c, rec, 32);
                if (cref_guard(rec, 1, 32, qtol, vmax2, hmin, hmax) != 1) *why = 3;
            }
            if (*why) {
                *groups = g + 1;
                return u + 1;
            }
        }
    }
    *groups = ng;
    return u;
}
