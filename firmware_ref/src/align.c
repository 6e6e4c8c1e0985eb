/* The static alignment's steps before navigation, the operations of ins_hil/core_parts/alignment.py
 * (Alignment.step) and core_parts/sensor_check.py (SensorCheck.add) in the same order: the levelling window with
 * the IMU's motion test (phase "level"), the start-up check's sums, and the gyro-only step of the heading phase. */
#include "ins_internal.h"

void ins_level_init(ins_level_t *l, double time, double still_delay, double frozen, double still_tau, double gyro2,
                    double accel2) {
    int i;
    l->time = time;
    l->still_delay = still_delay;
    l->frozen = frozen;
    l->still_tau = still_tau;
    l->gyro2 = gyro2;
    l->accel2 = accel2;
    l->first = l->n_win = l->n_pend = 0;
    for (i = 0; i < 3; ++i) l->f_sum[i] = l->w_sum[i] = K(0.0);
    l->t_win = 0.0;
    l->dev_w = l->dev_f = 0.0;
    l->moving = l->imu_moving = 0;
    l->have_pos = l->yaw_ready = 0;
}

/* d . d as plain products in NavCore's order (core_parts/alignment.py: x x + y y + z z; no fused multiply-add under
 * -ffp-contract=off), the same bits on any host */
static double dot3(const double d[3]) { return d[0] * d[0] + d[1] * d[1] + d[2] * d[2]; }

int ins_level_step(ins_level_t *l, const ins_real dtheta[3], const ins_real dvel[3], double dt, double t) {
    uint32_t k;
    double hold;
    int i;
    if (l->n_win + l->n_pend >= (uint32_t)INS_LEVEL_N) return INS_LEVEL_FULL;
    /* the IMU's motion test: the sample against the window's mean */
    if (l->t_win >= 0.5 && !l->imu_moving) {
        double a = dt / (l->still_tau + dt), dw[3], df[3];
        for (i = 0; i < 3; ++i) {
            dw[i] = (double)dtheta[i] / dt - (double)l->w_sum[i] / l->t_win;
            df[i] = (double)dvel[i] / dt - (double)l->f_sum[i] / l->t_win;
        }
        l->dev_w += a * (dot3(dw) - l->dev_w);
        l->dev_f += a * (dot3(df) - l->dev_f);
        if (l->dev_w > l->gyro2 || l->dev_f > l->accel2) l->imu_moving = l->moving = 1;
    }
    /* held back still_delay s (frozen s once the IMU saw motion), then into the window */
    k = (l->first + l->n_win + l->n_pend) % (uint32_t)INS_LEVEL_N;
    l->t[k] = t;
    l->dt[k] = dt;
    for (i = 0; i < 3; ++i) {
        l->dth[k][i] = dtheta[i];
        l->dv[k][i] = dvel[i];
    }
    l->n_pend++;
    hold = l->imu_moving ? l->frozen : l->still_delay;
    while (l->n_pend > 0) {
        k = (l->first + l->n_win) % (uint32_t)INS_LEVEL_N;
        if (!(t - l->t[k] > hold)) break;
        l->n_pend--;
        l->n_win++;
        l->t_win += l->dt[k];
        for (i = 0; i < 3; ++i) {
            l->f_sum[i] = l->f_sum[i] + l->dv[k][i];
            l->w_sum[i] = l->w_sum[i] + l->dth[k][i];
        }
    }
    /* the window keeps the last `time` s */
    while (l->n_win > 0 && l->t_win - l->dt[l->first] >= l->time) {
        k = l->first;
        l->t_win -= l->dt[k];
        for (i = 0; i < 3; ++i) {
            l->f_sum[i] = l->f_sum[i] - l->dv[k][i];
            l->w_sum[i] = l->w_sum[i] - l->dth[k][i];
        }
        l->first = (k + 1) % (uint32_t)INS_LEVEL_N;
        l->n_win--;
    }
    if (l->have_pos && (l->t_win >= l->time - 0.5 * dt || (l->moving && l->t_win >= 0.5)) &&
        (l->moving || l->yaw_ready))
        return INS_LEVEL_DUE;
    return 0;
}

void ins_imu_check_init(ins_imu_check_t *c, double window) {
    int i;
    c->window = window;
    c->n = 0;
    c->t = 0.0;
    for (i = 0; i < 3; ++i) c->sf[i] = c->sf2[i] = c->sw[i] = c->sw2[i] = K(0.0);
}

int ins_imu_check_add(ins_imu_check_t *c, const ins_real dtheta[3], const ins_real dvel[3], double dt) {
    int i;
    if (!(dt > 0.0)) return 0;
    for (i = 0; i < 3; ++i) {
        ins_real f = (ins_real)((double)dvel[i] / dt), w = (ins_real)((double)dtheta[i] / dt);
        c->sf[i] += f;
        c->sf2[i] += f * f;
        c->sw[i] += w;
        c->sw2[i] += w * w;
    }
    c->n++;
    c->t += dt;
    return c->t < c->window ? 0 : 1;
}

void ins_align_heading_step(ins_mech_t *m, ins_gsf_t *g, const ins_real dtheta[3], const ins_real dvel[3], ins_real dt,
                            double t_end, const ins_real bg[3], const ins_real ba[3], ins_real omega_b[3]) {
    ins_real a[3], u[3];
    int i;
    for (i = 0; i < 3; ++i) {
        a[i] = dtheta[i] - bg[i] * dt;
        u[i] = dvel[i] - ba[i] * dt;
    }
    if (g != NULL) ins_gsf_predict(g, a, dvel, dt, K(0.0));
    m->dt = dt;
    ins_mech_step(m, a, u);
    m->t = t_end;
    for (i = 0; i < 3; ++i) {
        m->v[i] = K(0.0);
        omega_b[i] = a[i] / dt;
    }
}
