/* ins_ref_bench: a fixed workload for instruction counting (valgrind --tool=callgrind):
 *   ins_ref_bench N_STEPS N_GNSS
 * runs N_STEPS IMU steps (mechanization + 15-state EKF predict) of a 100 Hz coordinated
 * turn, then N_GNSS GNSS position+velocity updates. Prints the final state. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "ins_ref.h"

int main(int argc, char **argv) {
    const double dt = 0.01, lat0 = 50.45 * 3.14159265358979323846 / 180.0, lon0 = 0.5;
    const ins_real q0[4] = {1, 0, 0, 0}, v0[3] = {0, 0, 0};
    ins_real dth[3], dv[3];
    ins_core_t core;
    ins_gnss_t g;
    long n, m, k;
    int acc = 0;
    if (argc != 3 || (n = strtol(argv[1], NULL, 10)) < 1 || (m = strtol(argv[2], NULL, 10)) < 0) {
        fprintf(stderr, "usage: ins_ref_bench N_STEPS N_GNSS\n");
        return 2;
    }
    ins_core_init(&core, q0, v0, lat0, lon0, 100.0, 0.0, (ins_real)dt, NULL, 1);
    for (k = 0; k < n; ++k) {
        /* level, slowly yawing, small wobble: keeps the state bounded */
        const double ph = 0.5 * (double)k * dt;
        dth[0] = (ins_real)(0.01 * sin(ph) * dt);
        dth[1] = (ins_real)(0.01 * cos(ph) * dt);
        dth[2] = (ins_real)(0.05 * dt);
        dv[0] = (ins_real)(0.0);
        dv[1] = (ins_real)(0.0);
        dv[2] = (ins_real)(-9.8114 * dt);
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
