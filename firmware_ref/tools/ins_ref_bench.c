/* ins_ref_bench: fixed workloads for instruction counting (valgrind --tool=callgrind):
 *   ins_ref_bench N_STEPS N_GNSS
 * runs N_STEPS IMU steps (mechanization + 15-state EKF predict) of a 100 Hz coordinated
 * turn, then N_GNSS GNSS position+velocity updates;
 *   ins_ref_bench --hist N_STEPS EVERY DELAY
 * runs N_STEPS IMU steps of 200 Hz through the delayed-fusion history (ins_hist_step; vibration noise on,
 * max_delay 0.3 s: the synthetic case of ins_hil.bench.core_replay.synthetic_rows) with, every EVERY steps, a
 * GNSS position valid now and its velocity valid DELAY steps earlier (a roll-back of DELAY steps when DELAY > 0).
 * Prints the final state.
 *   ins_ref_bench --digest
 * prints, for a few filter configurations (vibration noise, scale factors, cov_every, first order, NHC/ZUPT and
 * lever arm) of a wobbling 200 Hz run with late fixes, a hash of every bit of the state and the covariance after
 * every step and fix: two builds that print the same lines computed the same numbers (make test compares the build
 * with the AVX2 copies of the hot kernels, ins_internal.h INS_HOT, with one without them). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ins_ref.h"

static ins_hist_t hist; /* 1.8 MB: static */

static void imu(long k, double dt, ins_real dth[3], ins_real dv[3]) {
    /* level, slowly yawing, small wobble: keeps the state bounded */
    const double ph = 0.5 * (double)k * dt;
    dth[0] = (ins_real)(0.01 * sin(ph) * dt);
    dth[1] = (ins_real)(0.01 * cos(ph) * dt);
    dth[2] = (ins_real)(0.05 * dt);
    dv[0] = (ins_real)(0.0);
    dv[1] = (ins_real)(0.0);
    dv[2] = (ins_real)(-9.8114 * dt);
}

static uint64_t digest_h;
static void digest_mix(const void *p, size_t n) { /* FNV-1a */
    const unsigned char *b = (const unsigned char *)p;
    size_t i;
    for (i = 0; i < n; ++i) {
        digest_h ^= b[i];
        digest_h *= 1099511628211ULL;
    }
}
static void digest_core(const ins_core_t *c) {
    int i;
    digest_mix(c->mech.q, sizeof c->mech.q);
    digest_mix(c->mech.v, sizeof c->mech.v);
    digest_mix(&c->mech.lat, sizeof c->mech.lat);
    digest_mix(&c->mech.lon, sizeof c->mech.lon);
    digest_mix(&c->mech.h, sizeof c->mech.h);
    for (i = 0; i < c->ekf.nx; ++i) digest_mix(c->ekf.P[i], sizeof(ins_real) * (size_t)c->ekf.nx);
    digest_mix(c->ekf.bg, sizeof c->ekf.bg);
    digest_mix(c->ekf.ba, sizeof c->ekf.ba);
    digest_mix(c->ekf.sg, sizeof c->ekf.sg);
    digest_mix(c->ekf.sa, sizeof c->ekf.sa);
}

/* variant bits: 1 vibration noise, 2 scale factors (21 states), 4 cov_every 3, 8 first order, 16 NHC + ZUPT + lever */
static void digest_run(int variant, long n) {
    const double dt = 0.005, lat0 = 50.45 * 3.14159265358979323846 / 180.0, lon0 = 0.5;
    const ins_real q0[4] = {1, 0, 0, 0}, v0[3] = {2, 1, 0};
    ins_real dth[3], dv[3];
    ins_ekf_cfg_t cfg;
    ins_core_t core;
    ins_gnss_t g, gv;
    long k;
    int rp;
    ins_ekf_default_cfg(&cfg);
    if (variant & 1) {
        cfg.gyro_vib_gain = (ins_real)0.4;
        cfg.accel_vib_gain = (ins_real)0.6;
    }
    if (variant & 2) cfg.scale_factors = 1;
    if (variant & 4) cfg.cov_every = 3;
    if (variant & 8) cfg.second_order = 0;
    if (variant & 16) {
        cfg.nhc = cfg.zupt = 1;
        cfg.lever_arm[0] = (ins_real)0.3;
        cfg.lever_arm[2] = (ins_real)-0.1;
    }
    digest_h = 1469598103934665603ULL;
    ins_core_init(&core, q0, v0, lat0, lon0, 100.0, 0.0, (ins_real)dt, &cfg, 1);
    ins_hist_init(&hist, 0.3);
    for (k = 0; k < n; ++k) {
        const double ph = 0.7 * (double)k * dt;
        dth[0] = (ins_real)(0.02 * sin(ph) * dt);
        dth[1] = (ins_real)(0.03 * cos(1.3 * ph) * dt);
        dth[2] = (ins_real)(0.05 * dt);
        dv[0] = (ins_real)(0.3 * sin(0.5 * ph) * dt);
        dv[1] = (ins_real)(0.2 * cos(ph) * dt);
        dv[2] = (ins_real)(-9.8112 * dt);
        ins_hist_step(&hist, &core, dth, dv, core.mech.t + dt, (ins_real)dt);
        digest_core(&core);
        if ((k + 1) % 10 != 0) continue;
        g.t = core.mech.t; /* a position now, its velocity 20 steps earlier, a baro sample 4 steps late */
        g.lat = lat0 + 1e-7 * sin(ph);
        g.lon = lon0;
        g.h = 100.0;
        g.vel[0] = g.vel[1] = g.vel[2] = (ins_real)NAN;
        g.std_ne = (ins_real)0.5;
        g.std_d = (ins_real)0.8;
        g.std_vel = (ins_real)0.1;
        gv = g;
        gv.t = core.mech.t - 20.0 * dt;
        gv.lat = (double)NAN;
        gv.vel[0] = (ins_real)1.0;
        gv.vel[1] = (ins_real)0.5;
        gv.vel[2] = (ins_real)0.0;
        ins_hist_fuse_gnss_split(&hist, &core, &g, &gv, &rp, NULL, NULL);
        if (k % 50 == 9) ins_hist_fuse_baro(&hist, &core, core.mech.t - 0.02, 100.0);
        digest_core(&core);
    }
    printf("variant %2d: %016llx\n", variant, (unsigned long long)digest_h);
}

static int digest(void) {
    static const int vs[] = {0, 1, 2, 3, 4, 6, 7, 8, 10, 16, 17, 19, 23, 27};
    size_t i;
    for (i = 0; i < sizeof vs / sizeof vs[0]; ++i) digest_run(vs[i], 2000);
    return 0;
}

static int hist_workload(long n, long every, long delay) {
    const double dt = 0.005, lat0 = 50.45 * 3.14159265358979323846 / 180.0, lon0 = 0.5;
    const ins_real q0[4] = {1, 0, 0, 0}, v0[3] = {0, 0, 0};
    ins_real dth[3], dv[3];
    ins_ekf_cfg_t cfg;
    ins_core_t core;
    ins_gnss_t g, gv;
    long k;
    int acc = 0, rp;
    ins_ekf_default_cfg(&cfg);
    cfg.gyro_vib_gain = (ins_real)0.4;
    cfg.accel_vib_gain = (ins_real)0.6;
    ins_core_init(&core, q0, v0, lat0, lon0, 100.0, 0.0, (ins_real)dt, &cfg, 1);
    ins_hist_init(&hist, 0.3);
    for (k = 0; k < n; ++k) {
        imu(k, dt, dth, dv);
        dth[0] = dth[1] = (ins_real)0.0; /* yawing in place: at rest at the start point */
        dv[2] = (ins_real)(-9.8112 * dt);
        ins_hist_step(&hist, &core, dth, dv, core.mech.t + dt, (ins_real)dt);
        if ((k + 1) % every != 0) continue;
        g.t = core.mech.t;
        g.lat = lat0; /* at rest at the start point */
        g.lon = lon0;
        g.h = 100.0;
        g.vel[0] = g.vel[1] = g.vel[2] = (ins_real)NAN; /* the position alone */
        g.std_ne = (ins_real)0.02;
        g.std_d = (ins_real)0.04;
        g.std_vel = (ins_real)0.02;
        gv = g;
        gv.t = core.mech.t - (double)delay * dt;
        gv.lat = (double)NAN; /* the velocity alone, DELAY steps earlier */
        gv.vel[0] = gv.vel[1] = gv.vel[2] = (ins_real)0.0;
        acc += ins_hist_fuse_gnss_split(&hist, &core, &g, &gv, &rp, NULL, NULL) == 2;
        acc += rp == 1;
    }
    printf("%.12f %.12f %.6f %d rollbacks %u pos %u/%u vel %u/%u\n", core.mech.lat, core.mech.lon, core.mech.h, acc,
           (unsigned)hist.rollbacks, (unsigned)core.ekf.accepted[0], (unsigned)core.ekf.rejected[0],
           (unsigned)core.ekf.accepted[1], (unsigned)core.ekf.rejected[1]);
    return 0;
}

int main(int argc, char **argv) {
    const double dt = 0.01, lat0 = 50.45 * 3.14159265358979323846 / 180.0, lon0 = 0.5;
    const ins_real q0[4] = {1, 0, 0, 0}, v0[3] = {0, 0, 0};
    ins_real dth[3], dv[3];
    ins_core_t core;
    ins_gnss_t g;
    long n, m, k, every, delay;
    int acc = 0;
    if (argc == 2 && strcmp(argv[1], "--digest") == 0) return digest();
    if (argc == 5 && strcmp(argv[1], "--hist") == 0) {
        if ((n = strtol(argv[2], NULL, 10)) < 1 || (every = strtol(argv[3], NULL, 10)) < 1 ||
            (delay = strtol(argv[4], NULL, 10)) < 0) {
            fprintf(stderr, "usage: ins_ref_bench --hist N_STEPS EVERY DELAY\n");
            return 2;
        }
        return hist_workload(n, every, delay);
    }
    if (argc != 3 || (n = strtol(argv[1], NULL, 10)) < 1 || (m = strtol(argv[2], NULL, 10)) < 0) {
        fprintf(stderr, "usage: ins_ref_bench N_STEPS N_GNSS | ins_ref_bench --hist N_STEPS EVERY DELAY | "
                        "ins_ref_bench --digest\n");
        return 2;
    }
    ins_core_init(&core, q0, v0, lat0, lon0, 100.0, 0.0, (ins_real)dt, NULL, 1);
    for (k = 0; k < n; ++k) {
        imu(k, dt, dth, dv);
        ins_core_step(&core, dth, dv, core.mech.t + dt);
    }
    g.t = core.mech.t;
    g.lat = core.mech.lat + 1e-7;
    g.lon = core.mech.lon - 1e-7;
    g.h = core.mech.h + 0.5;
    g.vel[0] = core.mech.v[0];
    g.vel[1] = core.mech.v[1];
    g.vel[2] = core.mech.v[2];
    g.std_ne = (ins_real)1.0;
    g.std_d = (ins_real)2.0;
    g.std_vel = (ins_real)0.1;
    for (k = 0; k < m; ++k) acc += ins_core_fuse_gnss(&core, &g) == 3;
    printf("%.9f %.9f %.3f %d\n", core.mech.lat, core.mech.lon, core.mech.h, acc);
    return 0;
}
