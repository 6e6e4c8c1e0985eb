/* Parity-space FDI for redundant single-axis gyros (DIGEST_000 sections 5.1-5.2). */
#include "ins_internal.h"
#include "parity_cone5.h"

void ins_fdi_cone5_u2t(ins_real u2t[INS_FDI_M * INS_FDI_N]) {
    int i, k;
    for (i = 0; i < INS_FDI_M; ++i)
        for (k = 0; k < INS_FDI_N; ++k) u2t[i * INS_FDI_N + k] = (ins_real)INS_CONE5_U2T[i][k];
}

void ins_fdi_parity(const ins_real u2t[INS_FDI_M * INS_FDI_N], const ins_real y[INS_FDI_N], ins_real threshold,
                    ins_fdi_result_t *r) {
    int i, k, best = 0;
    r->p2 = K(0.0);
    for (i = 0; i < INS_FDI_M; ++i) { /* book eq. 5.12: p = U2^T y */
        ins_real acc = K(0.0);
        for (k = 0; k < INS_FDI_N; ++k) acc += u2t[i * INS_FDI_N + k] * y[k];
        r->p[i] = acc;
        r->p2 += acc * acc;
    }
    for (k = 0; k < INS_FDI_N; ++k) {
        /* u_k = k-th row of U2 (column k of U2^T); J(k) = |p|^2 - (u_k.p)^2/|u_k|^2 (eq. 5.17 corrected) */
        ins_real up = K(0.0), uu = K(0.0);
        for (i = 0; i < INS_FDI_M; ++i) {
            up += u2t[i * INS_FDI_N + k] * r->p[i];
            uu += u2t[i * INS_FDI_N + k] * u2t[i * INS_FDI_N + k];
        }
        r->rho[k] = up / uu; /* eq. 5.16 */
        r->J[k] = r->p2 - up * up / uu;
        if (r->J[k] < r->J[best]) best = k;
    }
    r->detected = r->p2 > threshold;
    r->isolated = r->detected ? best : -1;
}
