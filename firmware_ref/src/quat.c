/* Quaternion / DCM utilities and the book's attitude update (DIGEST_000 sections 1.2, 2.2). */
#include "ins_internal.h"

void ins_quat_mul(const ins_real p[4], const ins_real q[4], ins_real r[4]) {
    /* Hamilton product, scalar first; p (x) q = M(q) p of book eq. 2.16 */
    r[0] = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3];
    r[1] = p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2];
    r[2] = p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1];
    r[3] = p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0];
}

void ins_quat_normalize(ins_real q[4]) {
    ins_real n = K(1.0) / RS(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    int i;
    if (q[0] < K(0.0)) n = -n;
    for (i = 0; i < 4; ++i) q[i] *= n;
}

void ins_quat_from_rotvec(const ins_real v[3], ins_real q[4]) {
    /* exact: (cos(a/2), sin(a/2)/a * v); series below 1e-6 rad (as rotation.quat_from_rotvec) */
    const ins_real a2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    ins_real c, k;
    if (a2 < K(1e-12)) {
        c = K(1.0) - a2 / K(8.0) + a2 * a2 / K(384.0);
        k = K(0.5) - a2 / K(48.0) + a2 * a2 / K(3840.0);
    } else {
        const ins_real a = RS(a2);
        c = RCOS(K(0.5) * a);
        k = RSIN(K(0.5) * a) / a;
    }
    q[0] = c;
    q[1] = k * v[0];
    q[2] = k * v[1];
    q[3] = k * v[2];
}

void ins_dcm_from_quat(const ins_real q[4], ins_real c[9]) {
    /* C_b^n = A^T, A of book eq. 2.5 */
    const ins_real q00 = q[0] * q[0], q11 = q[1] * q[1], q22 = q[2] * q[2], q33 = q[3] * q[3];
    c[0] = q00 + q11 - q22 - q33;
    c[1] = K(2.0) * (q[1] * q[2] - q[0] * q[3]);
    c[2] = K(2.0) * (q[1] * q[3] + q[0] * q[2]);
    c[3] = K(2.0) * (q[1] * q[2] + q[0] * q[3]);
    c[4] = q00 - q11 + q22 - q33;
    c[5] = K(2.0) * (q[2] * q[3] - q[0] * q[1]);
    c[6] = K(2.0) * (q[1] * q[3] - q[0] * q[2]);
    c[7] = K(2.0) * (q[2] * q[3] + q[0] * q[1]);
    c[8] = q00 - q11 - q22 + q33;
}

void ins_quat_from_dcm(const ins_real c[9], ins_real q[4]) {
    /* Shepperd: pick the largest of 4q0^2, 4q1^2, 4q2^2, 4q3^2 (book eq. 2.7 is the first branch) */
    const ins_real tr = c[0] + c[4] + c[8];
    ins_real s;
    if (tr >= c[0] && tr >= c[4] && tr >= c[8]) {
        s = K(2.0) * RS(K(1.0) + tr);
        q[0] = K(0.25) * s;
        q[1] = (c[7] - c[5]) / s;
        q[2] = (c[2] - c[6]) / s;
        q[3] = (c[3] - c[1]) / s;
    } else if (c[0] >= c[4] && c[0] >= c[8]) {
        s = K(2.0) * RS(K(1.0) + c[0] - c[4] - c[8]);
        q[0] = (c[7] - c[5]) / s;
        q[1] = K(0.25) * s;
        q[2] = (c[1] + c[3]) / s;
        q[3] = (c[2] + c[6]) / s;
    } else if (c[4] >= c[8]) {
        s = K(2.0) * RS(K(1.0) + c[4] - c[0] - c[8]);
        q[0] = (c[2] - c[6]) / s;
        q[1] = (c[1] + c[3]) / s;
        q[2] = K(0.25) * s;
        q[3] = (c[5] + c[7]) / s;
    } else {
        s = K(2.0) * RS(K(1.0) + c[8] - c[0] - c[4]);
        q[0] = (c[3] - c[1]) / s;
        q[1] = (c[2] + c[6]) / s;
        q[2] = (c[5] + c[7]) / s;
        q[3] = K(0.25) * s;
    }
    ins_quat_normalize(q);
}

void ins_euler_from_quat(const ins_real q[4], ins_real rpy[3]) {
    /* book eq. 2.11 */
    ins_real s = K(-2.0) * (q[1] * q[3] - q[0] * q[2]);
    if (s > K(1.0)) s = K(1.0);
    if (s < K(-1.0)) s = K(-1.0);
    rpy[0] = RATAN2(K(2.0) * (q[2] * q[3] + q[0] * q[1]), q[0] * q[0] - q[1] * q[1] - q[2] * q[2] + q[3] * q[3]);
    rpy[1] = RASIN(s);
    rpy[2] = RATAN2(K(2.0) * (q[1] * q[2] + q[3] * q[0]), q[0] * q[0] + q[1] * q[1] - q[2] * q[2] - q[3] * q[3]);
}

void ins_quat_from_euler(const ins_real rpy[3], ins_real q[4]) {
    /* standard ZYX (DIGEST_000 section 1.3, not the book's eq. 2.3 as printed) */
    const ins_real cr = RCOS(K(0.5) * rpy[0]), sr = RSIN(K(0.5) * rpy[0]);
    const ins_real cp = RCOS(K(0.5) * rpy[1]), sp = RSIN(K(0.5) * rpy[1]);
    const ins_real cy = RCOS(K(0.5) * rpy[2]), sy = RSIN(K(0.5) * rpy[2]);
    q[0] = cr * cp * cy + sr * sp * sy;
    q[1] = sr * cp * cy - cr * sp * sy;
    q[2] = cr * sp * cy + sr * cp * sy;
    q[3] = cr * cp * sy - sr * sp * cy;
    ins_quat_normalize(q);
}

/* ---------------------------------------------- book eq. 2.18 + 2.19 */

void ins_book_att_init(ins_book_att_t *a, const ins_real q0[4], ins_real dt) {
    int i;
    for (i = 0; i < 4; ++i) a->lam[i] = q0[i];
    for (i = 0; i < 3; ++i) a->w1[i] = a->w2[i] = a->th_prev[i] = K(0.0);
    a->dt = dt;
    a->n = 0;
}

void ins_book_att_step_th(ins_book_att_t *a, const ins_real th[3]) {
    ins_real d[4], lam[4];
    const ins_real n2 = th[0] * th[0] + th[1] * th[1] + th[2] * th[2];
    int i;
    /* book eq. 2.18: [1 - |th|^2/12 ; th/2 - (th_i x th_{i-1})/24] */
    d[0] = K(1.0) - n2 / K(12.0);
    d[1] = K(0.5) * th[0] - (th[1] * a->th_prev[2] - th[2] * a->th_prev[1]) / K(24.0);
    d[2] = K(0.5) * th[1] - (th[2] * a->th_prev[0] - th[0] * a->th_prev[2]) / K(24.0);
    d[3] = K(0.5) * th[2] - (th[0] * a->th_prev[1] - th[1] * a->th_prev[0]) / K(24.0);
    ins_quat_mul(a->lam, d, lam); /* book eq. 2.15/2.16 */
    for (i = 0; i < 4; ++i) a->lam[i] = lam[i];
    for (i = 0; i < 3; ++i) a->th_prev[i] = th[i];
    a->n++;
}

void ins_book_att_step(ins_book_att_t *a, const ins_real w[3]) {
    ins_real th[3];
    int i;
    if (a->n == 0) {
        for (i = 0; i < 3; ++i) th[i] = a->dt * w[i]; /* start-up: Euler */
    } else if (a->n == 1) {
        for (i = 0; i < 3; ++i) th[i] = K(0.5) * a->dt * (w[i] + a->w1[i]); /* start-up: trapezoid */
    } else {
        for (i = 0; i < 3; ++i) /* book eq. 2.19: quadratic spline over t_{i-2}..t_i */
            th[i] = a->dt / K(12.0) * (K(5.0) * w[i] + K(8.0) * a->w1[i] - a->w2[i]);
    }
    ins_book_att_step_th(a, th);
    for (i = 0; i < 3; ++i) {
        a->w2[i] = a->w1[i];
        a->w1[i] = w[i];
    }
}

void ins_book_att_quat(const ins_book_att_t *a, ins_real q[4]) {
    int i;
    for (i = 0; i < 4; ++i) q[i] = a->lam[i];
    ins_quat_normalize(q);
}
