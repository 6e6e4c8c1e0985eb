/* The core: mechanization + EKF predict per IMU step, GNSS/baro updates. */
#include "ins_internal.h"

void ins_core_init(ins_core_t *c, const ins_real q[4], const ins_real v[3], ins_pos lat, ins_pos lon, ins_pos h,
                   double t, ins_real dt, const ins_ekf_cfg_t *cfg, int filter) {
    ins_ekf_cfg_t def;
    if (cfg == NULL) {
        ins_ekf_default_cfg(&def);
        cfg = &def;
    }
    ins_mech_init(&c->mech, q, v, lat, lon, h, t, dt);
    ins_ekf_init(&c->ekf, cfg, dt);
    c->filter = filter;
    c->steps = 0;
}

void ins_core_step(ins_core_t *c, const ins_real dth[3], const ins_real dv[3], double t_end) {
    ins_real a[3], u[3];
    const ins_real dt = c->mech.dt;
    int i;
    for (i = 0; i < 3; ++i) { /* bias-corrected increments (book eq. 3.45) */
        a[i] = dth[i] - c->ekf.bg[i] * dt;
        u[i] = dv[i] - c->ekf.ba[i] * dt;
    }
    ins_mech_step(&c->mech, a, u);
    c->mech.t = t_end;
    if (c->filter) ins_ekf_predict(&c->ekf, &c->mech);
    c->steps++;
}

void ins_core_run(ins_core_t *c, const ins_real *inc, const double *t_end, size_t n, ins_out_t *out) {
    size_t k;
    for (k = 0; k < n; ++k) {
        const double te = t_end != NULL ? t_end[k] : c->mech.t + (double)c->mech.dt;
        ins_core_step(c, inc + 6 * k, inc + 6 * k + 3, te);
        if (out != NULL) ins_core_output(c, out + k);
    }
}

static void unit(ins_real h[INS_NX], int j) {
    int i;
    for (i = 0; i < INS_NX; ++i) h[i] = K(0.0);
    h[j] = K(1.0);
}

int ins_core_fuse_gnss(ins_core_t *c, const ins_gnss_t *g) {
    ins_mech_t *m = &c->mech;
    const ins_real lat = (ins_real)m->lat, h = (ins_real)m->h;
    const ins_real sl = RSIN(lat), w2 = K(1.0) - K(INS_E2_WGS84) * sl * sl;
    const ins_real rn = K(INS_A_WGS84) / RS(w2), rm = rn * (K(1.0) - K(INS_E2_WGS84)) / w2;
    ins_real hv[INS_NX], z[3];
    int i, n = 0;
    /* position residuals true - computed in metres NED (seed 001 eq. 148 converted with M+h, (N+h) cos) */
    z[0] = (ins_real)(g->lat - m->lat) * (rm + h);
    z[1] = (ins_real)(g->lon - m->lon) * (rn + h) * RCOS(lat);
    z[2] = -(ins_real)(g->h - m->h);
    for (i = 0; i < 3; ++i) {
        const ins_real sd = i < 2 ? g->std_ne : g->std_d;
        unit(hv, i);
        ins_ekf_update_scalar(&c->ekf, hv, z[i], sd * sd);
        n++;
    }
    if (g->vel[0] == g->vel[0] && g->vel[1] == g->vel[1] && g->vel[2] == g->vel[2]) { /* not NaN */
        for (i = 0; i < 3; ++i) {
            unit(hv, 3 + i);
            ins_ekf_update_scalar(&c->ekf, hv, g->vel[i] - m->v[i], g->std_vel * g->std_vel);
            n++;
        }
    }
    ins_ekf_feedback(&c->ekf, m);
    return n;
}

void ins_core_fuse_baro(ins_core_t *c, ins_real altitude, ins_real std) {
    ins_real hv[INS_NX];
    unit(hv, 2);
    ins_ekf_update_scalar(&c->ekf, hv, -(altitude + c->ekf.baro_offset - (ins_real)c->mech.h), std * std);
    ins_ekf_feedback(&c->ekf, &c->mech);
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
