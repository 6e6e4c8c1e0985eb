/* Internal helpers of the reference core: scalar-type switch for libm and literals. */
#ifndef INS_INTERNAL_H
#define INS_INTERNAL_H

#include <math.h>

#include "ins_ref.h"

#ifdef INS_REF_FLOAT
#define RS(x) sqrtf(x)
#define RSIN(x) sinf(x)
#define RCOS(x) cosf(x)
#define RATAN2(y, x) atan2f(y, x)
#define RASIN(x) asinf(x)
#define RFABS(x) fabsf(x)
#else
#define RS(x) sqrt(x)
#define RSIN(x) sin(x)
#define RCOS(x) cos(x)
#define RATAN2(y, x) atan2(y, x)
#define RASIN(x) asin(x)
#define RFABS(x) fabs(x)
#endif
/* The hot kernels (the covariance propagation, the scalar update): an AVX2 copy besides the baseline one, chosen when
 * the library is loaded (GCC's target_clones: an ifunc, glibc), on x86-64 with GCC >= 6 and glibc; elsewhere, or
 * with -DINS_NO_CLONES, the baseline function alone. The copies are the same C99 operations in the same order, and
 * without -ffast-math no compiler reorders them (the AVX2 target has no FMA to contract into): their results are
 * equal bit for bit (firmware_ref/tests/test_ins_ref.c checks it where both run). */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 6 && defined(__GLIBC__) && \
    !defined(INS_NO_CLONES)
#define INS_HOT __attribute__((target_clones("avx2", "default")))
#else
#define INS_HOT
#endif

/* a literal in the scalar type (the constant is rounded at compile time) */
#define K(x) ((ins_real)(x))

/* WGS84, seed 001 Table 1 - the same expressions as ins_hil/nav/earth.py, so
 * the double build holds bit-identical constants. */
#define INS_A_WGS84 6378137.0
#define INS_F_WGS84 (1.0 / 298.257223563)
#define INS_B_WGS84 (INS_A_WGS84 * (1.0 - INS_F_WGS84))
#define INS_E2_WGS84 (INS_F_WGS84 * (2.0 - INS_F_WGS84)) /* seed 001 eq. 1 */
#define INS_OMEGA_E 7.292115e-5
#define INS_GAMMA_A 9.7803253359
#define INS_GAMMA_B 9.8321849378
#define INS_K_SOMIGLIANA (INS_B_WGS84 * INS_GAMMA_B / (INS_A_WGS84 * INS_GAMMA_A) - 1.0) /* seed 001 eq. 12 */

#endif
