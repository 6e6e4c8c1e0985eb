/* ins_ref_bench: fixed workloads for instruction counting (valgrind --tool=callgrind):
 *   ins_ref_bench N_STEPS N_GNSS
 * runs N_STEPS IMU steps (mechanization + 15-state EKF predict) of a 100 Hz coordinated
 * turn, then N_GNSS GNSS position+velocity updates;
 *   ins_ref_bench --hist N_STEPS EVERY DELAY
 * runs N_STEPS IMU steps of 200 Hz through the delayed-fusion history (ins_hist_step; vibration noise on,
 * max_delay 0.3 s: the synthetic case of ins_hil.bench.core_replay.synthetic_rows) with, every EVERY steps, a
 * GNSS position valid now and its velocity valid DELAY steps earlier (a roll-back of DELAY steps when DELAY > 0).
 * Prints the final state. */
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
    if (argc == 5 && strcmp(argv[1], "--hist") == 0) {
        if ((n = strtol(argv[2], NULL, 10)) < 1 || (every = strtol(argv[3], NULL, 10)) < 1 ||
            (delay = strtol(argv[4], NULL, 10)) < 0) {
            fprintf(stderr, "usage: ins_ref_bench --hist N_STEPS EVERY DELAY\n");
            return 2;
        }
        return hist_workload(n, every, delay);
    }
    if (argc != 3 || (n = strtol(argv[1], NULL, 10)) < 1 || (m = strtol(argv[2], NULL, 10)) < 0) {
        fprintf(stderr, "usage: ins_ref_bench N_STEPS N_GNSS | ins_ref_bench --hist N_STEPS EVERY DELAY\n");
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
