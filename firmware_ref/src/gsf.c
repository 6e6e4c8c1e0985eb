/* The GNSS-velocity yaw bank (EKF-GSF), the operations of ins_hil/fusion/yaw_gsf.py in the same order (the
 * alignment's steps that feed it: align.c). */
#include "ins_internal.h"

#define G0 K(9.80665) /* m/s^2, the 1 g of the accelerometer-gain fade */
#define PI_R K(3.14159265358979323846)

#ifdef INS_REF_FLOAT
#define REXP(x) expf(x)
#define RFMOD(x, y) fmodf(x, y)
#else
#define REXP(x) exp(x)
#define RFMOD(x, y) fmod(x, y)
#endif

/* (a + pi) mod 2 pi - pi with the floor modulo (numpy's remainder) */
static ins_real wrap(ins_real a) {
    const ins_real tau = K(2.0) * PI_R;
    ins_real m = RFMOD(a + PI_R, tau);
    if (m != K(0.0) && m < K(0.0)) m += tau;
    return m - PI_R;
}

void ins_gsf_init(ins_gsf_t *g, int n) {
    int m, i;
    if (n < 2) n = 2;
    if (n > INS_GSF_N) n = INS_GSF_N;
    g->n = n;
    g->tilt_gain = K(0.2);
    g->gyro_bias_gain = K(0.04);
    g->gyro_bias_max = K(0.05);
    g->bias_spin_max = K(0.175);
    g->gyro_noise = K(0.1);
    g->accel_noise = K(2.0);
    g->vel_std_min = K(0.5);
    g->tilt_aligned = 0;
    g->started = 0;
    for (m = 0; m < INS_GSF_N; ++m) {
        for (i = 0; i < 9; ++i) {
            g->R[m][i] = (i % 4 == 0) ? K(1.0) : K(0.0);
            g->P[m][i] = K(0.0);
        }
        for (i = 0; i < 3; ++i) g->bias[m][i] = g->X[m][i] = K(0.0);
        g->W[m] = K(1.0) / (ins_real)n;
    }
    for (i = 0; i < 3; ++i) g->accel[i] = K(0.0);
    g->yaw = K(0.0);
    g->yaw_var = (ins_real)INFINITY;
    g->updates = 0;
}

/* exp([phi x]) (Rodrigues): I + a K + b K K */
static void exp_so3(const ins_real phi[3], ins_real E[9]) {
    ins_real th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2], th = RS(th2), a, b, Km[9], KK[9];
    int i, j, k;
    if (th < K(1e-6)) {
        a = K(1.0) - th2 / K(6.0);
        b = K(0.5) - th2 / K(24.0);
    } else {
        a = RSIN(th) / th;
        b = (K(1.0) - RCOS(th)) / th2;
    }
    Km[0] = K(0.0); Km[1] = -phi[2]; Km[2] = phi[1];
    Km[3] = phi[2]; Km[4] = K(0.0); Km[5] = -phi[0];
    Km[6] = -phi[1]; Km[7] = phi[0]; Km[8] = K(0.0);
    for (i = 0; i < 3; ++i)
        for (j = 0; j < 3; ++j) {
            ins_real s = K(0.0);
            for (k = 0; k < 3; ++k) s += Km[3 * i + k] * Km[3 * k + j];
            KK[3 * i + j] = s;
        }
    for (i = 0; i < 9; ++i) E[i] = ((i % 4 == 0) ? K(1.0) : K(0.0)) + a * Km[i] + b * KK[i];
}

static void mat3_mul(const ins_real A[9], const ins_real B[9], ins_real C[9]) {
    int i, j, k;
    for (i = 0; i < 3; ++i)
        for (j = 0; j < 3; ++j) {
            ins_real s = K(0.0);
            for (k = 0; k < 3; ++k) s += A[3 * i + k] * B[3 * k + j];
            C[3 * i + j] = s;
        }
}

/* each model's yaw from its C_b^n (321 Euler yaw, or the 312 one near +-90 deg of pitch/roll) */
static ins_real model_yaw(const ins_real R[9]) {
    if (RFABS(R[6]) < RFABS(R[7])) return RATAN2(R[3], R[0]);
    return RATAN2(-R[1], R[4]);
}

static void align_tilt(ins_gsf_t *g, const ins_real f[3]) {
    ins_real nf = RS(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]), d[3], north[3], east[3], xd, nn;
    int m, i;
    for (i = 0; i < 3; ++i) d[i] = -f[i] / nf;
    xd = d[0]; /* x . d with x = (1, 0, 0) */
    for (i = 0; i < 3; ++i) north[i] = (i == 0 ? K(1.0) : K(0.0)) - d[i] * xd;
    nn = RS(north[0] * north[0] + north[1] * north[1] + north[2] * north[2]);
    for (i = 0; i < 3; ++i) north[i] /= nn;
    east[0] = d[1] * north[2] - d[2] * north[1];
    east[1] = d[2] * north[0] - d[0] * north[2];
    east[2] = d[0] * north[1] - d[1] * north[0];
    for (m = 0; m < g->n; ++m)
        for (i = 0; i < 3; ++i) {
            g->R[m][i] = north[i];
            g->R[m][3 + i] = east[i];
            g->R[m][6 + i] = d[i];
        }
    g->tilt_aligned = 1;
}

static void predict_ekf(ins_gsf_t *g, const ins_real dvel[3], ins_real dt) {
    ins_real q_v = (g->accel_noise * dt) * (g->accel_noise * dt), q_psi = (g->gyro_noise * dt) * (g->gyro_noise * dt);
    int m, i, j, k;
    for (m = 0; m < g->n; ++m) {
        const ins_real *R = g->R[m];
        ins_real dv[3], F[9], FP[9], P[9];
        g->X[m][2] = model_yaw(R);
        for (i = 0; i < 3; ++i) dv[i] = R[3 * i] * dvel[0] + R[3 * i + 1] * dvel[1] + R[3 * i + 2] * dvel[2];
        g->X[m][0] += dv[0];
        g->X[m][1] += dv[1];
        for (i = 0; i < 9; ++i) F[i] = (i % 4 == 0) ? K(1.0) : K(0.0);
        F[2] = -dv[1];
        F[5] = dv[0];
        mat3_mul(F, g->P[m], FP);
        for (i = 0; i < 3; ++i) /* FP F^T */
            for (j = 0; j < 3; ++j) {
                ins_real s = K(0.0);
                for (k = 0; k < 3; ++k) s += FP[3 * i + k] * F[3 * j + k];
                P[3 * i + j] = s;
            }
        P[0] += q_v;
        P[4] += q_v;
        P[8] += q_psi;
        for (i = 0; i < 3; ++i)
            for (j = 0; j < 3; ++j) g->P[m][3 * i + j] = K(0.5) * (P[3 * i + j] + P[3 * j + i]);
    }
}

void ins_gsf_predict(ins_gsf_t *g, const ins_real dtheta[3], const ins_real dvel[3], ins_real dt,
                     ins_real forward_speed) {
    ins_real dt_s = dt > K(1e-3) ? dt : K(1e-3), f[3], k, acc[3], an, gain, fade;
    int m, i;
    for (i = 0; i < 3; ++i) f[i] = dvel[i] / dt_s;
    if (!g->tilt_aligned) {
        ins_real fn = RS(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
        if (K(0.9) * G0 < fn && fn < K(1.1) * G0) { /* at (near) rest: the specific force is gravity's */
            for (i = 0; i < 3; ++i) g->accel[i] = f[i];
            align_tilt(g, f);
        }
        return;
    }
    k = K(10.0) * dt_s * g->tilt_gain;
    if (k > K(1.0)) k = K(1.0);
    for (i = 0; i < 3; ++i) g->accel[i] = g->accel[i] + k * (f[i] - g->accel[i]);
    for (i = 0; i < 3; ++i) acc[i] = g->accel[i];
    if (forward_speed > K(0.0)) {
        acc[0] = acc[0] - K(0.0);
        acc[1] = acc[1] - forward_speed * (dtheta[2] / dt_s);
        acc[2] = acc[2] - (-forward_speed * (dtheta[1] / dt_s));
    }
    an = RS(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2]);
    fade = K(2.0) * RFABS(an - G0) / G0;
    if (fade > K(1.0)) fade = K(1.0);
    gain = g->tilt_gain * ((K(1.0) - fade) * (K(1.0) - fade));
    for (m = 0; m < g->n; ++m) {
        ins_real tilt[3] = {K(0.0), K(0.0), K(0.0)}, rate[3], phi[3], E[9], Rn[9];
        ins_real *R = g->R[m], *b = g->bias[m];
        if (gain > K(0.0) && an > K(0.0)) {
            const ins_real *d = R + 6, k_t = gain / an; /* NED down in body; down x acc turns down onto -f */
            tilt[0] = (d[1] * acc[2] - d[2] * acc[1]) * k_t;
            tilt[1] = (d[2] * acc[0] - d[0] * acc[2]) * k_t;
            tilt[2] = (d[0] * acc[1] - d[1] * acc[0]) * k_t;
        }
        for (i = 0; i < 3; ++i) rate[i] = dtheta[i] / dt_s - b[i];
        if (RS(rate[0] * rate[0] + rate[1] * rate[1] + rate[2] * rate[2]) < g->bias_spin_max)
            for (i = 0; i < 3; ++i) b[i] = b[i] - tilt[i] * (g->gyro_bias_gain * dt_s);
        for (i = 0; i < 3; ++i) {
            if (b[i] < -g->gyro_bias_max) b[i] = -g->gyro_bias_max;
            if (b[i] > g->gyro_bias_max) b[i] = g->gyro_bias_max;
            phi[i] = dtheta[i] + (tilt[i] - b[i]) * dt_s;
        }
        exp_so3(phi, E);
        mat3_mul(R, E, Rn);
        for (i = 0; i < 9; ++i) R[i] = Rn[i];
    }
    if (g->started) predict_ekf(g, dvel, dt_s);
}

/* turn a model's attitude about NED down by dpsi (rad): Rz(dpsi) R */
static void turn(ins_real R[9], ins_real dpsi) {
    ins_real c = RCOS(dpsi), s = RSIN(dpsi), r0, r1;
    int j;
    for (j = 0; j < 3; ++j) {
        r0 = c * R[j] + (-s) * R[3 + j];
        r1 = s * R[j] + c * R[3 + j];
        R[j] = r0;
        R[3 + j] = r1; /* the down row stays */
    }
}

static void composite(ins_gsf_t *g) {
    ins_real ss = K(0.0), sc = K(0.0), v = K(0.0);
    int m;
    for (m = 0; m < g->n; ++m) {
        ss += g->W[m] * RSIN(g->X[m][2]);
        sc += g->W[m] * RCOS(g->X[m][2]);
    }
    g->yaw = RATAN2(ss, sc);
    for (m = 0; m < g->n; ++m) {
        ins_real d = wrap(g->X[m][2] - g->yaw);
        v += g->W[m] * (g->P[m][8] + d * d);
    }
    g->yaw_var = v;
}

void ins_gsf_fuse_vel(ins_gsf_t *g, const ins_real vel_ne[2], ins_real std) {
    ins_real s = std > g->vel_std_min ? std : g->vel_std_min, var = s * s, total = K(0.0), w[INS_GSF_N];
    int m, i, j;
    const int n = g->n;
    if (!g->tilt_aligned) return;
    if (!g->started) {
        ins_real inc = K(2.0) * PI_R / (ins_real)n;
        for (m = 0; m < n; ++m) {
            ins_real psi0 = -PI_R + K(0.5) * inc + inc * (ins_real)m;
            turn(g->R[m], psi0 - model_yaw(g->R[m]));
            g->X[m][0] = vel_ne[0];
            g->X[m][1] = vel_ne[1];
            g->X[m][2] = psi0;
            for (i = 0; i < 9; ++i) g->P[m][i] = K(0.0);
            g->P[m][0] = var;
            g->P[m][4] = var;
            g->P[m][8] = (K(0.5) * inc) * (K(0.5) * inc);
            g->W[m] = K(1.0) / (ins_real)n;
        }
        g->started = 1;
        composite(g);
        return;
    }
    for (m = 0; m < n; ++m) {
        ins_real *P = g->P[m], *X = g->X[m];
        ins_real innov[2], S[4], det, Si[4], d2, Kg[6], dx[3], scale, Pn[9], dens;
        innov[0] = X[0] - vel_ne[0];
        innov[1] = X[1] - vel_ne[1];
        S[0] = P[0] + var; S[1] = P[1] + K(0.0); S[2] = P[3] + K(0.0); S[3] = P[4] + var;
        det = S[0] * S[3] - S[1] * S[2];
        Si[0] = S[3] / det; Si[3] = S[0] / det; Si[1] = -S[1] / det; Si[2] = -S[2] / det;
        d2 = innov[0] * (Si[0] * innov[0] + Si[1] * innov[1]) + innov[1] * (Si[2] * innov[0] + Si[3] * innov[1]);
        for (i = 0; i < 3; ++i)
            for (j = 0; j < 2; ++j) Kg[2 * i + j] = P[3 * i] * Si[j] + P[3 * i + 1] * Si[2 + j];
        scale = d2 > K(25.0) ? RS(K(25.0) / d2) : K(1.0);
        for (i = 0; i < 3; ++i) dx[i] = (Kg[2 * i] * innov[0] + Kg[2 * i + 1] * innov[1]) * scale;
        for (i = 0; i < 3; ++i) X[i] = X[i] - dx[i];
        X[2] = wrap(X[2]);
        for (i = 0; i < 3; ++i)
            for (j = 0; j < 3; ++j) Pn[3 * i + j] = P[3 * i + j] - (Kg[2 * i] * P[j] + Kg[2 * i + 1] * P[3 + j]);
        for (i = 0; i < 3; ++i)
            for (j = 0; j < 3; ++j) P[3 * i + j] = K(0.5) * (Pn[3 * i + j] + Pn[3 * j + i]);
        turn(g->R[m], -dx[2]);
        dens = REXP(K(-0.5) * d2) / (K(2.0) * PI_R * RS(det));
        w[m] = dens * g->W[m];
        if (w[m] < K(0.0)) w[m] = K(0.0); /* a NaN stays: the weights are then kept */
        total += w[m];
    }
    if (total > K(0.0) && total < (ins_real)INFINITY)
        for (m = 0; m < n; ++m) g->W[m] = w[m] / total;
    g->updates++;
    composite(g);
}
