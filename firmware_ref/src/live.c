/* The live gateway's per-sample path in C (ins_hil.fdi.monitor, ins_hil.runtime.mavlink_msgs): compiled into the
 * Python extension only (firmware_ref/cffi_build.py, the live block), not part of the embedded core.
 *
 * - live_fdi_step: one epoch of one FDI parity group (ins_hil.fdi.monitor._Group.step) in its common case: at
 *   least 4 healthy rows, none missing or repeating its last output, no fault run about to trip. It declines (returns 1,
 *   nothing changed) whenever the Python step has more to do, which then runs as before.
 * - live_odometry: MAVLink 2 ODOMETRY of a navigation state, framed (MessageBase._emit / _Frame.frame with
 *   FcMessages._send_odometry's numbers): the same operations in the same order as the Python floats, the same
 *   libm, so the same bytes.
 * - live_frame / live_crc: MAVLink 2 framing of an unsigned link and CRC-16/MCRF4XX (X.25). */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "live.h"

/* ------------------------------------------------------------------------------------------ FDI parity group */

int live_fdi_step(live_fdi_group_t *g, double t, const double *y, double *est) {
    const int n = g->n, nh = g->nh, m = g->m, r = m + 3;
    double out[LIVE_FDI_MAX_ROWS + 3], ema[LIVE_FDI_MAX_ROWS], yh[LIVE_FDI_MAX_ROWS], s = 0.0, se = 0.0;
    int i, j;
    long long run = g->run, srun;
    if (n > LIVE_FDI_MAX_ROWS || nh > n || m < 1 || m != nh - 3) return 1;
    for (i = 0; i < n; ++i) /* a missing row (NaN), an infinite one or a repeated output: the Python step */
        if (!isfinite(y[i]) || y[i] == g->prev[i]) return 1;
    for (i = 0; i < nh; ++i) yh[i] = y[g->hidx[i]]; /* the healthy rows */
    for (i = 0; i < r; ++i) { /* [parity p (whitened); LS estimate] = M y_h */
        const double *row = g->M + (size_t)i * (size_t)nh;
        double acc = 0.0;
        for (j = 0; j < nh; ++j) acc = acc + row[j] * yh[j];
        out[i] = acc;
    }
    for (i = 0; i < m; ++i) {
        s = s + out[i] * out[i];
        ema[i] = g->ema[i] * g->oma;
        ema[i] = ema[i] + g->alpha * out[i];
        se = se + ema[i] * ema[i];
    }
    if (s > g->thr_fast) ++run;
    else run = 0;
    srun = se > g->thr_slow ? g->srun + 1 : 0;
    if (run >= g->persistence || srun >= g->persistence) return 1; /* a test trips: isolation in Python */
    /* commit */
    memcpy(g->buf + (size_t)g->pos * (size_t)n, y, (size_t)n * sizeof(double));
    g->tbuf[g->pos] = t;
    g->pos = g->pos + 1 == g->L ? 0 : g->pos + 1;
    memcpy(g->prev, y, (size_t)n * sizeof(double));
    memcpy(g->ema, ema, (size_t)m * sizeof(double));
    if (run) {
        if (g->run == 0) g->onset = t;
        for (i = 0; i < nh; ++i) { /* score += (Un p)^2 over the healthy rows */
            const double *row = g->Un + (size_t)i * (size_t)m;
            double acc = 0.0;
            for (j = 0; j < m; ++j) acc = acc + row[j] * out[j];
            g->score[i] = g->score[i] + acc * acc;
        }
    } else if (g->run) {
        for (i = 0; i < nh; ++i) g->score[i] = 0.0;
    }
    g->run = run;
    g->srun = srun;
    est[0] = out[m];
    est[1] = out[m + 1];
    est[2] = out[m + 2];
    return 0;
}

/* ----------------------------------------------------------------------------------------- MAVLink framing */

uint16_t live_crc(const uint8_t *p, size_t n, uint16_t crc) {
    size_t i;
    for (i = 0; i < n; ++i) {
        uint8_t tmp = (uint8_t)(p[i] ^ (uint8_t)(crc & 0xFF));
        tmp = (uint8_t)(tmp ^ (uint8_t)(tmp << 4));
        crc = (uint16_t)((crc >> 8) ^ ((uint16_t)tmp << 8) ^ ((uint16_t)tmp << 3) ^ (tmp >> 4));
    }
    return crc;
}

size_t live_frame(uint8_t *out, const uint8_t *payload, size_t len, uint32_t msgid, uint8_t crc_extra, uint8_t seq,
                  uint8_t sysid, uint8_t compid) {
    uint16_t crc;
    while (len > 1 && payload[len - 1] == 0) --len; /* MAVLink 2 trims trailing zeros (one byte kept) */
    out[0] = 0xFD;
    out[1] = (uint8_t)len;
    out[2] = 0;
    out[3] = 0;
    out[4] = seq;
    out[5] = sysid;
    out[6] = compid;
    out[7] = (uint8_t)(msgid & 0xFF);
    out[8] = (uint8_t)((msgid >> 8) & 0xFF);
    out[9] = (uint8_t)(msgid >> 16);
    memmove(out + 10, payload, len);
    crc = live_crc(out + 1, 9 + len, 0xFFFF);
    crc = live_crc(&crc_extra, 1, crc);
    out[10 + len] = (uint8_t)(crc & 0xFF);
    out[11 + len] = (uint8_t)(crc >> 8);
    return 12 + len;
}

/* -------------------------------------------------------------------------------------------------- ODOMETRY */

/* CPython's math.hypot of two floats (Modules/mathmodule.c, vector_norm: exact squares and sums, one correction) */
typedef struct {
    double hi, lo;
} dl_t;
static dl_t dl_mul(double x, double y) {
    dl_t r;
    r.hi = x * y;
    r.lo = fma(x, y, -r.hi);
    return r;
}
static dl_t dl_fast_sum(double a, double b) {
    dl_t r;
    double z;
    r.hi = a + b;
    z = r.hi - a;
    r.lo = b - z;
    return r;
}
static double py_hypot2(double a, double b) {
    double v[2], mx = 0.0, x, h, scale, csum = 1.0, frac1 = 0.0, frac2 = 0.0;
    dl_t pr, sm;
    int i, e, nan = 0;
    v[0] = fabs(a);
    v[1] = fabs(b);
    for (i = 0; i < 2; ++i) {
        nan |= isnan(v[i]);
        if (v[i] > mx) mx = v[i];
    }
    if (isinf(mx)) return mx;
    if (nan) return NAN;
    if (mx == 0.0) return mx;
    frexp(mx, &e);
    if (e < -1023) return 2.2250738585072014e-308 * py_hypot2(v[0] / 2.2250738585072014e-308, v[1] / 2.2250738585072014e-308);
    scale = ldexp(1.0, -e);
    for (i = 0; i < 2; ++i) {
        x = v[i] * scale;
        pr = dl_mul(x, x);
        sm = dl_fast_sum(csum, pr.hi);
        csum = sm.hi;
        frac1 += pr.lo;
        frac2 += sm.lo;
    }
    h = sqrt(csum - 1.0 + (frac1 + frac2));
    pr = dl_mul(-h, h);
    sm = dl_fast_sum(csum, pr.hi);
    csum = sm.hi;
    frac1 += pr.lo;
    frac2 += sm.lo;
    x = csum - 1.0 + (frac1 + frac2);
    h += x / (2.0 * h);
    return h / scale;
}

double live_hypot(double a, double b) { return py_hypot2(a, b); }

/* x**2 as Python computes it (the libm's pow, never folded into x * x) */
static double (*volatile pow_fn)(double, double) = pow;

static void put_u64(uint8_t *p, uint64_t v) {
    int i;
    for (i = 0; i < 8; ++i) p[i] = (uint8_t)(v >> (8 * i));
}
/* struct.pack('<f'): the value rounded to float; a finite value beyond the float range is an error (as Python) */
static int put_f32(uint8_t *p, double v) {
    float f = (float)v;
    uint32_t u;
    if (isinf(f) && !isinf(v)) return -1;
    memcpy(&u, &f, 4);
    p[0] = (uint8_t)u;
    p[1] = (uint8_t)(u >> 8);
    p[2] = (uint8_t)(u >> 16);
    p[3] = (uint8_t)(u >> 24);
    return 0;
}

int live_odometry(uint8_t *out, const double *s, const double *home, double *prev, int reset, const int *ids) {
    /* s: t, lat, lon, h, q[4], v_ned[3], omega_b[3], std_pos[3], std_vel[3], std_att[3] (23)
     * home: ECEF x, y, z of the home, C_e^n at the home (9, row-major), the ellipsoid's a and e^2, the position
     *   jump's threshold squared (m^2, fc.JUMP_M^2) (15)
     * prev: [have, t, d[3], v[3]] of the last ODOMETRY (updated here)
     * ids: frame_id, child_frame_id, reset_counter, estimator_type, quality, seq, sysid, compid
     * Returns the frame's length, + 65536 when the position jumped (reset_counter + 1 in the message); a value the
     * message cannot carry (time, a float beyond the float range, a finite sigma whose square is not): -1, -2 when it
     * jumped (as struct.pack or ** raises); a NaN among s: -3, nothing written (prev unchanged: the caller's Python
     * builder sends it and hands its prev back) */
    const double t = s[0], lat = s[1], lon = s[2], hh = s[3], a_e = home[12], e2 = home[13];
    const double q0 = s[4], q1 = s[5], q2 = s[6], q3 = s[7], vn = s[8], ve = s[9], vd = s[10];
    double sl, nn, ncl, x, y, z, dx, dy, dz, d[3], c[3][3], vb[3], pc[21], vc[21], t_us;
    double q00, q11, q22, q33;
    uint8_t pay[233];
    int i, k, rc = ids[2], jump = 0;
    const double *cen = home + 3;
    for (i = 0; i < 23; ++i) /* a NaN's sign through + and * follows the compiler's operand order, not CPython's: */
        if (isnan(s[i])) return -3; /* such a state goes the Python way (nothing written here) */
    /* MessageBase._home_ned: earth.ecef_xyz, then C_e^n (r_e - r_e,home) */
    sl = sin(lat);
    nn = a_e / sqrt(1.0 - e2 * sl * sl);
    ncl = (nn + hh) * cos(lat);
    x = ncl * cos(lon);
    y = ncl * sin(lon);
    z = (nn * (1.0 - e2) + hh) * sl;
    dx = x - home[0];
    dy = y - home[1];
    dz = z - home[2];
    for (i = 0; i < 3; ++i) d[i] = cen[3 * i] * dx + cen[3 * i + 1] * dy + cen[3 * i + 2] * dz;
    if (prev[0] != 0.0 && !reset) { /* a step of the position beyond what the velocity explains (home[14]: fc.JUMP_M²) */
        const double h2 = 0.5 * (t - prev[1]);
        const double dn = d[0] - prev[2] - h2 * (vn + prev[5]);
        const double de = d[1] - prev[3] - h2 * (ve + prev[6]);
        const double dd = d[2] - prev[4] - h2 * (vd + prev[7]);
        if (dn * dn + de * de + dd * dd > home[14]) {
            rc = (rc + 1) & 0xFF;
            jump = 1;
        }
    }
    prev[0] = 1.0;
    prev[1] = t;
    prev[2] = d[0];
    prev[3] = d[1];
    prev[4] = d[2];
    prev[5] = vn;
    prev[6] = ve;
    prev[7] = vd;
    /* rotation.dcm_rows */
    q00 = q0 * q0;
    q11 = q1 * q1;
    q22 = q2 * q2;
    q33 = q3 * q3;
    c[0][0] = q00 + q11 - q22 - q33;
    c[0][1] = 2.0 * (q1 * q2 - q0 * q3);
    c[0][2] = 2.0 * (q1 * q3 + q0 * q2);
    c[1][0] = 2.0 * (q1 * q2 + q0 * q3);
    c[1][1] = q00 - q11 + q22 - q33;
    c[1][2] = 2.0 * (q2 * q3 - q0 * q1);
    c[2][0] = 2.0 * (q1 * q3 - q0 * q2);
    c[2][1] = 2.0 * (q2 * q3 + q0 * q1);
    c[2][2] = q00 - q11 - q22 + q33;
    for (i = 0; i < 3; ++i) vb[i] = c[0][i] * vn + c[1][i] * ve + c[2][i] * vd;
    {
        const double sp0 = s[14], sp1 = s[15], sp2 = s[16];
        for (i = 0; i < 21; ++i) pc[i] = vc[i] = 0.0;
        if ((sp0 > 0.0 || sp1 > 0.0 || sp2 > 0.0) && !(isnan(sp0) || isnan(sp1) || isnan(sp2))) {
            const double *sa = s + 20, *sv = s + 17;
            double m1, sth, cth, n2, sph, cph, tth, u, a[3], b[3], g[3], w0, w1, w2;
            pc[0] = pow_fn(sp0, 2.0);
            pc[6] = pow_fn(sp1, 2.0);
            pc[11] = pow_fn(sp2, 2.0);
            if ((isinf(pc[0]) && !isinf(sp0)) || (isinf(pc[6]) && !isinf(sp1)) || (isinf(pc[11]) && !isinf(sp2)))
                return -1 - jump; /* CPython's float ** raises OverflowError on a finite result beyond the range */
            /* fc._euler_cov (min/max as Python's: NaN keeps the first argument) */
            m1 = -c[2][0] < 1.0 ? -c[2][0] : 1.0;
            sth = m1 > -1.0 ? m1 : -1.0;
            cth = sqrt(1.0 - sth * sth);
            cth = 1e-3 > cth ? 1e-3 : cth;
            n2 = py_hypot2(c[2][1], c[2][2]);
            if (n2 == 0.0) n2 = 1.0;
            sph = c[2][1] / n2;
            cph = c[2][2] / n2;
            tth = sth / cth;
            for (k = 0; k < 3; ++k) {
                u = c[k][1] * sph + c[k][2] * cph;
                a[k] = c[k][0] + u * tth;
                b[k] = c[k][1] * cph - c[k][2] * sph;
                g[k] = u / cth;
            }
            w0 = sa[0] * sa[0];
            w1 = sa[1] * sa[1];
            w2 = sa[2] * sa[2];
            pc[15] = w0 * a[0] * a[0] + w1 * a[1] * a[1] + w2 * a[2] * a[2];
            pc[16] = w0 * a[0] * b[0] + w1 * a[1] * b[1] + w2 * a[2] * b[2];
            pc[17] = w0 * a[0] * g[0] + w1 * a[1] * g[1] + w2 * a[2] * g[2];
            pc[18] = w0 * b[0] * b[0] + w1 * b[1] * b[1] + w2 * b[2] * b[2];
            pc[19] = w0 * b[0] * g[0] + w1 * b[1] * g[1] + w2 * b[2] * g[2];
            pc[20] = w0 * g[0] * g[0] + w1 * g[1] * g[1] + w2 * g[2] * g[2];
            /* fc._body_cov */
            w0 = sv[0] * sv[0];
            w1 = sv[1] * sv[1];
            w2 = sv[2] * sv[2];
            vc[0] = w0 * c[0][0] * c[0][0] + w1 * c[1][0] * c[1][0] + w2 * c[2][0] * c[2][0];
            vc[1] = w0 * c[0][0] * c[0][1] + w1 * c[1][0] * c[1][1] + w2 * c[2][0] * c[2][1];
            vc[2] = w0 * c[0][0] * c[0][2] + w1 * c[1][0] * c[1][2] + w2 * c[2][0] * c[2][2];
            vc[6] = w0 * c[0][1] * c[0][1] + w1 * c[1][1] * c[1][1] + w2 * c[2][1] * c[2][1];
            vc[7] = w0 * c[0][1] * c[0][2] + w1 * c[1][1] * c[1][2] + w2 * c[2][1] * c[2][2];
            vc[11] = w0 * c[0][2] * c[0][2] + w1 * c[1][2] * c[1][2] + w2 * c[2][2] * c[2][2];
        } else { /* unknown: NaN first element */
            pc[0] = vc[0] = NAN;
        }
    }
    /* round(t * 1e6) (half to even), packed as uint64 */
    t_us = rint(t * 1e6);
    if (!(t_us >= 0.0 && t_us < 18446744073709551616.0)) return -1 - jump;
    put_u64(pay, (uint64_t)t_us);
    k = 8;
    {
        const double f[13] = {d[0], d[1], d[2], q0, q1, q2, q3, vb[0], vb[1], vb[2], s[11], s[12], s[13]};
        for (i = 0; i < 13; ++i, k += 4)
            if (put_f32(pay + k, f[i])) return -1 - jump;
    }
    for (i = 0; i < 21; ++i, k += 4)
        if (put_f32(pay + k, pc[i])) return -1 - jump;
    for (i = 0; i < 21; ++i, k += 4)
        if (put_f32(pay + k, vc[i])) return -1 - jump;
    pay[k++] = (uint8_t)ids[0];
    pay[k++] = (uint8_t)ids[1];
    pay[k++] = (uint8_t)rc;
    pay[k++] = (uint8_t)ids[3];
    pay[k++] = (uint8_t)(int8_t)ids[4];
    return (int)live_frame(out, pay, (size_t)k, 331u, 91u, (uint8_t)ids[5], (uint8_t)ids[6], (uint8_t)ids[7]) |
           (jump << 16);
}
