/* NED strapdown mechanization on increments.
 *
 * Mirrors ins_hil.nav.mechanization.StrapdownNED.step operation by operation
 * (same formulas, same evaluation order), so that the double build agrees
 * with the Python to round-off. See that module for the derivation: seed 001
 * eqs. 55-59 (DIGEST_001_004 sections 1.5-1.7) in NED with two-sample
 * coning/sculling corrections.
 */
#include "ins_internal.h"

static void rotvec_quat(ins_real x, ins_real y, ins_real z, ins_real r[4]) {
    const ins_real v[3] = {x, y, z};
    ins_quat_from_rotvec(v, r);
}

void ins_mech_init(ins_mech_t *m, const ins_real q[4], const ins_real v[3], ins_pos lat, ins_pos lon, ins_pos h,
                   double t, ins_real dt) {
    int i;
    for (i = 0; i < 4; ++i) m->q[i] = q[i];
    for (i = 0; i < 3; ++i) {
        m->v[i] = v[i];
        m->dth_prev[i] = m->dv_prev[i] = K(0.0);
        m->f_ned[i] = m->omega_ie[i] = m->omega_en[i] = K(0.0);
    }
    m->lat = lat;
    m->lon = lon;
    m->h = h;
    m->t = t;
    m->dt = dt;
    m->have_prev = 0;
    m->coning = m->sculling = m->earth_rate = 1;
    m->renorm_every = 1;
    m->n = 0;
}

void ins_mech_step(ins_mech_t *m, const ins_real dth[3], const ins_real dvel[3]) {
    const ins_real dt = m->dt;
    const ins_real lat = (ins_real)m->lat, h = (ins_real)m->h;
    const ins_real vN = m->v[0], vE = m->v[1], vD = m->v[2];
    const ins_real ax = dth[0], ay = dth[1], az = dth[2];
    const ins_real ux = dvel[0], uy = dvel[1], uz = dvel[2];
    ins_real slat, clat, w2, rn, rm, rm0, ieN, ieD, enN, enE, enD, inN, inE, inD, wN, wE, wD;
    ins_real px, py, pz, bx = K(0.0), by = K(0.0), bz = K(0.0), cx = K(0.0), cy = K(0.0), cz = K(0.0);
    ins_real dx, dy, dz, q0, q1, q2, q3, q00, q11, q22, q33, nN, nE, nD, zN, zE, zD, fN, fE, fD;
    ins_real hm0, latm, s2, g, cN, cE, cD, vN1, vE1, vD1;
    ins_real r[4], a0, a1, a2, a3, mN, mE, mD, hm;
    ins_pos h1, lat1;

    /* body rotation vector with coning correction (1/12) dth_{k-1} x dth_k */
    px = ax;
    py = ay;
    pz = az;
    if (m->have_prev) {
        bx = m->dth_prev[0];
        by = m->dth_prev[1];
        bz = m->dth_prev[2];
        cx = m->dv_prev[0];
        cy = m->dv_prev[1];
        cz = m->dv_prev[2];
        if (m->coning) {
            px += (by * az - bz * ay) / K(12.0);
            py += (bz * ax - bx * az) / K(12.0);
            pz += (bx * ay - by * ax) / K(12.0);
        }
    }
    /* dv + 1/2 dth x dv (rotation) + sculling 1/12 (dth_{k-1} x dv + dv_{k-1} x dth) */
    dx = ux + K(0.5) * (ay * uz - az * uy);
    dy = uy + K(0.5) * (az * ux - ax * uz);
    dz = uz + K(0.5) * (ax * uy - ay * ux);
    if (m->sculling && m->have_prev) {
        dx += ((by * uz - bz * uy) + (cy * az - cz * ay)) / K(12.0);
        dy += ((bz * ux - bx * uz) + (cz * ax - cx * az)) / K(12.0);
        dz += ((bx * uy - by * ux) + (cx * ay - cy * ax)) / K(12.0);
    }

    /* C_b^n(k-1) dv_b */
    q0 = m->q[0];
    q1 = m->q[1];
    q2 = m->q[2];
    q3 = m->q[3];
    q00 = q0 * q0;
    q11 = q1 * q1;
    q22 = q2 * q2;
    q33 = q3 * q3;
    nN = (q00 + q11 - q22 - q33) * dx + K(2.0) * (q1 * q2 - q0 * q3) * dy + K(2.0) * (q1 * q3 + q0 * q2) * dz;
    nE = K(2.0) * (q1 * q2 + q0 * q3) * dx + (q00 - q11 + q22 - q33) * dy + K(2.0) * (q2 * q3 - q0 * q1) * dz;
    nD = K(2.0) * (q1 * q3 - q0 * q2) * dx + K(2.0) * (q2 * q3 + q0 * q1) * dy + (q00 - q11 - q22 + q33) * dz;

    /* mid-interval position, extrapolated with the start velocity and the start meridian radius (an O(dt^2)
       position error: the rates, gravity and radii taken there are second order in the step); latm in double */
    slat = RSIN(lat);
    w2 = K(1.0) - K(INS_E2_WGS84) * slat * slat;
    rm0 = K(INS_A_WGS84) * (K(1.0) - K(INS_E2_WGS84)) / (w2 * RS(w2)); /* seed 001 eq. 3 */
    hm0 = h - K(0.5) * vD * dt;
    latm = (ins_real)(m->lat + (ins_pos)(K(0.5) * vN / (rm0 + h) * dt));
    slat = RSIN(latm);
    clat = RCOS(latm);
    w2 = K(1.0) - K(INS_E2_WGS84) * slat * slat;
    rn = K(INS_A_WGS84) / RS(w2);              /* seed 001 eq. 2 */
    rm = rn * (K(1.0) - K(INS_E2_WGS84)) / w2; /* seed 001 eq. 3 */
    /* gravity at the mid-interval point (seed 001 eqs. 12, 16) */
    s2 = slat * slat;
    g = K(INS_GAMMA_A) * (K(1.0) + K(INS_K_SOMIGLIANA) * s2) / RS(w2) - (K(3.0877e-6) - K(4.4e-9) * s2) * hm0 +
        K(0.72e-12) * hm0 * hm0;
    if (m->earth_rate) {
        const ins_real rnh = rn + hm0, rmh = rm + hm0, tlat = slat / clat;
        ieN = K(INS_OMEGA_E) * clat; /* omega_ie^n, seed 001 eq. 67 in NED */
        ieD = -K(INS_OMEGA_E) * slat;
        /* mid-interval velocity predicted with the start velocity's transport rate (frame rotation, Coriolis) */
        enN = vE / rnh;
        enE = -vN / rmh;
        enD = -vE * tlat / rnh;
        zN = (ieN + enN) * dt;
        zE = enE * dt;
        zD = (ieD + enD) * dt;
        fN = nN - K(0.5) * (zE * nD - zD * nE);
        fE = nE - K(0.5) * (zD * nN - zN * nD);
        fD = nD - K(0.5) * (zN * nE - zE * nN);
        cN = K(2.0) * ieN + enN;
        cE = enE;
        cD = K(2.0) * ieD + enD;
        wN = vN + K(0.5) * (fN + (K(0.0) - (cE * vD - cD * vE)) * dt);
        wE = vE + K(0.5) * (fE - (cD * vN - cN * vD) * dt);
        wD = vD + K(0.5) * (fD + (g - (cN * vE - cE * vN)) * dt);
        enN = wE / rnh; /* omega_en^n, transport rate, at the mid-interval state */
        enE = -wN / rmh;
        enD = -wE * tlat / rnh;
    } else {
        ieN = ieD = enN = enE = enD = wN = wE = wD = K(0.0);
    }
    inN = ieN + enN;
    inE = enE;
    inD = ieD + enD;

    /* nav-frame rotation over the interval: (I - 1/2 [zeta x]), zeta = omega_in^n dt */
    zN = inN * dt;
    zE = inE * dt;
    zD = inD * dt;
    fN = nN - K(0.5) * (zE * nD - zD * nE);
    fE = nE - K(0.5) * (zD * nN - zN * nD);
    fD = nD - K(0.5) * (zN * nE - zE * nN);
    m->f_ned[0] = fN / dt;
    m->f_ned[1] = fE / dt;
    m->f_ned[2] = fD / dt;

    /* Coriolis/transport -(2 omega_ie + omega_en) x v at the mid-interval state, plus gravity (seed 001 eq. 57) */
    cN = K(2.0) * ieN + enN;
    cE = enE;
    cD = K(2.0) * ieD + enD;
    vN1 = vN + fN + (K(0.0) - (cE * wD - cD * wE)) * dt;
    vE1 = vE + fE - (cD * wN - cN * wD) * dt;
    vD1 = vD + fD + (g - (cN * wE - cE * wN)) * dt;

    /* attitude: q(-zeta) (x) q (x) q(phi)  (book eq. 2.15/2.16 for the body part) */
    rotvec_quat(px, py, pz, r);
    a0 = q0 * r[0] - q1 * r[1] - q2 * r[2] - q3 * r[3];
    a1 = q0 * r[1] + q1 * r[0] + q2 * r[3] - q3 * r[2];
    a2 = q0 * r[2] - q1 * r[3] + q2 * r[0] + q3 * r[1];
    a3 = q0 * r[3] + q1 * r[2] - q2 * r[1] + q3 * r[0];
    if (m->earth_rate) {
        ins_real e[4], b0, b1, b2, b3;
        rotvec_quat(-zN, -zE, -zD, e);
        b0 = e[0] * a0 - e[1] * a1 - e[2] * a2 - e[3] * a3;
        b1 = e[0] * a1 + e[1] * a0 + e[2] * a3 - e[3] * a2;
        b2 = e[0] * a2 - e[1] * a3 + e[2] * a0 + e[3] * a1;
        b3 = e[0] * a3 + e[1] * a2 - e[2] * a1 + e[3] * a0;
        a0 = b0;
        a1 = b1;
        a2 = b2;
        a3 = b3;
    }
    m->n++;
    if (m->renorm_every > 0 && m->n % m->renorm_every == 0) {
        ins_real nq = K(1.0) / RS(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3);
        if (a0 < K(0.0)) nq = -nq;
        a0 = a0 * nq;
        a1 = a1 * nq;
        a2 = a2 * nq;
        a3 = a3 * nq;
    }

    /* position: trapezoidal in velocity, radii at the mid-interval latitude (seed 001 eq. 55/56 in NED);
       lat/lon/h in double */
    mN = K(0.5) * (vN + vN1);
    mE = K(0.5) * (vE + vE1);
    mD = K(0.5) * (vD + vD1);
    h1 = m->h - (ins_pos)(mD * dt);
    hm = (ins_real)(0.5 * (m->h + h1));
    lat1 = m->lat + (ins_pos)(mN / (rm + hm) * dt);
    m->lon = m->lon + (ins_pos)(mE / ((rn + hm) * clat) * dt);

    m->q[0] = a0;
    m->q[1] = a1;
    m->q[2] = a2;
    m->q[3] = a3;
    m->v[0] = vN1;
    m->v[1] = vE1;
    m->v[2] = vD1;
    m->lat = lat1;
    m->h = h1;
    m->t += (double)dt;
    m->dth_prev[0] = ax;
    m->dth_prev[1] = ay;
    m->dth_prev[2] = az;
    m->dv_prev[0] = ux;
    m->dv_prev[1] = uy;
    m->dv_prev[2] = uz;
    m->have_prev = 1;
    m->omega_ie[0] = ieN;
    m->omega_ie[1] = K(0.0);
    m->omega_ie[2] = ieD;
    m->omega_en[0] = enN;
    m->omega_en[1] = enE;
    m->omega_en[2] = enD;
}
