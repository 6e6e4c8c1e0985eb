"""cffi (API mode) build of the C reference core into ``ins_hil._cref`` (double)
and ``ins_hil._cref_f32`` (float, ``-DINS_REF_FLOAT``).

Referenced from setup.py ``cffi_modules``, so ``pip install .`` and
``pip install -e .`` compile the same sources as ``make -C firmware_ref``.
"""

from __future__ import annotations

import os
from pathlib import Path

from cffi import FFI

_HERE = Path(__file__).resolve().parent
_SOURCES = ["quat.c", "mech.c", "ekf.c", "core.c", "fdi.c", "frame.c", "gsf.c", "align.c", "live.c"]


def _rel(p: Path) -> str:
    # setuptools wants source paths relative to the project root (the cwd of setup.py)
    try:
        return os.path.relpath(p)
    except ValueError:  # pragma: no cover - other drive on Windows
        return str(p)


_CDEF = """
typedef {real} ins_real;
typedef double ins_pos;
#define INS_NX 21
#define INS_FDI_N 5
#define INS_FDI_M 2
typedef struct {{
    ins_real q[4]; ins_real v[3]; ins_pos lat, lon, h; double t; ins_real dt;
    ins_real f_ned[3]; ins_real omega_ie[3]; ins_real omega_en[3];
    ins_real dth_prev[3], dv_prev[3]; int have_prev; ...;
}} ins_mech_t;
typedef struct {{
    ins_real gyro_arw, accel_vrw, gyro_bias_sigma, gyro_bias_tau, accel_bias_sigma, accel_bias_tau;
    ins_real p0_pos, p0_vel, p0_att, p0_yaw, p0_bg, p0_ba;
    int second_order; ins_real gate_gnss, gate_baro; int gnss_reset_after;
    ins_real gnss_min_std_ne, gnss_min_std_d, gnss_min_std_vel; int use_gnss_vel; ins_real baro_std;
    int have_baro_offset; double baro_offset; double baro_offset_tau;
    ins_real lever_arm[3]; ins_real gnss_std_scale; ins_real gyro_vib_gain, accel_vib_gain, vib_tau; int cov_every;
    int nhc, nhc_vertical, zupt, zaru;
    ins_real nhc_std, nhc_std_vertical, nhc_rate, nhc_min_speed;
    ins_real zupt_std, zupt_gyro, zupt_accel, zupt_time, zupt_tau, zupt_max_speed, zaru_std;
    ins_real aids_gate; ins_real g_local;
    int have_mag; ins_real mag_ref[3], mag_std, mag_gate;
    int hold, have_hold_pos; double hold_lat, hold_lon, hold_h;
    ins_real hold_after, hold_std, hold_vel_std, hold_rate, hold_gate;
    ins_real gap_accel_sigma, gap_rate_sigma;
    int scale_factors; ins_real gyro_sf_sigma, accel_sf_sigma, sf_tau, p0_sg, p0_sa[3];
}} ins_ekf_cfg_t;
typedef struct {{
    ins_real P[21][21]; ins_real x[21]; ins_real bg[3], ba[3]; ins_real qc[21]; int nx; ins_real sg[3], sa[3];
    ins_pos baro_offset; int have_baro_offset; double baro_offset_var, t_baro, t_gnss_ok; ins_pos h_gnss;
    double gnss_var_d, baro_dt, gnss_dt; ins_real g_local;
    uint32_t accepted[7], rejected[7], consecutive[7]; ins_real last_ratio[7];
    uint32_t n_predict; ...;
}} ins_ekf_t;
typedef struct ins_out_s {{ double t; ...; }} ins_out_t;
#define INS_GSF_N 8
typedef struct {{
    int n; int tilt_aligned, started; ins_real W[8]; ins_real yaw, yaw_var; uint32_t updates; ...;
}} ins_gsf_t;
typedef struct {{ ins_mech_t mech; ins_ekf_t ekf; int filter; uint32_t steps; ins_out_t *pub; }} ins_core_t;
#define INS_LEVEL_N 8192
#define INS_LEVEL_DUE 1
#define INS_LEVEL_FULL 2
#define CREF_LEVEL_CHECKED 4
#define CREF_LEVEL_BAD 8
typedef struct {{
    double t[8192], dt[8192]; ins_real dth[8192][3], dv[8192][3]; uint32_t first, n_win, n_pend;
    ins_real f_sum[3], w_sum[3]; double t_win; double dev_w, dev_f; int moving, imu_moving; int have_pos, yaw_ready;
    ...;
}} ins_level_t;
typedef struct {{ double window, t; uint32_t n; ins_real sf[3], sf2[3], sw[3], sw2[3]; }} ins_imu_check_t;
typedef struct {{ uint32_t snap_n; uint32_t meas_n; double max_delay; uint32_t rollbacks, too_old; ...; }} ins_hist_t;
typedef struct {{
    ins_real lam[4]; ins_real w1[3]; ins_real w2[3]; ins_real th_prev[3]; ins_real dt; uint32_t n;
}} ins_book_att_t;
typedef struct {{
    ins_real p[2]; ins_real p2; ins_real J[5]; ins_real rho[5]; int detected; int isolated;
}} ins_fdi_result_t;

void ins_quat_mul(const ins_real p[4], const ins_real q[4], ins_real r[4]);
void ins_quat_from_rotvec(const ins_real v[3], ins_real q[4]);
void ins_dcm_from_quat(const ins_real q[4], ins_real c[9]);
void ins_book_att_init(ins_book_att_t *a, const ins_real q0[4], ins_real dt);
void ins_book_att_step(ins_book_att_t *a, const ins_real w[3]);
void ins_book_att_quat(const ins_book_att_t *a, ins_real q[4]);
void ins_ekf_default_cfg(ins_ekf_cfg_t *cfg);
void ins_fdi_cone5_u2t(ins_real u2t[10]);
void ins_fdi_parity(const ins_real u2t[10], const ins_real y[5], ins_real threshold, ins_fdi_result_t *r);
uint16_t ins_crc16_ccitt(const uint8_t *data, size_t n, uint16_t init);

/* glue in double for the Python wrapper (both variants) */
int cref_scalar_bits(void);
void cref_init(ins_core_t *c, const double q[4], const double v[3], double lat, double lon, double h, double t,
               double dt, const ins_ekf_cfg_t *cfg, int filter);
void cref_step(ins_core_t *c, const double dth[3], const double dv[3], double t_end);
void cref_state(const ins_core_t *c, double out[32]);
void cref_pub_state(const ins_core_t *c, double out[32]);
void cref_run(ins_core_t *c, ins_hist_t *h, const double *inc, const double *t_end, const double *dts, size_t n,
              double *out, size_t out_stride, int pub);
size_t cref_guard(const double *rows, size_t n, size_t stride, double qtol, double vmax2, double hmin, double hmax);
void cref_hist_init(ins_hist_t *h, double max_delay);
void cref_hstep(ins_core_t *c, ins_hist_t *h, const double dth[3], const double dv[3], double t_end, double dt);
int cref_hfuse_gnss(ins_core_t *c, ins_hist_t *hs, double t, double lat, double lon, double h, const double vel[3],
                    double std_ne, double std_d, double std_vel);
int cref_hfuse_baro(ins_core_t *c, ins_hist_t *hs, double t, double altitude);
int cref_hfuse_mag(ins_core_t *c, ins_hist_t *hs, double t, const double field[3]);
int cref_gfuse_gnss(ins_core_t *c, ins_hist_t *hs, double t, double lat, double lon, double h, double vn, double ve,
                    double vd, double std_ne, double std_d, double std_vel, double o[8]);
int cref_gfuse_gnss_split(ins_core_t *c, ins_hist_t *hs, double t, double vel_delay, double lat, double lon, double h,
                          double vn, double ve, double vd, double std_ne, double std_d, double std_vel, double o[8]);
int cref_gfuse_baro(ins_core_t *c, ins_hist_t *hs, double t, double altitude, double o[4]);
size_t cref_run_baro(ins_core_t *c, ins_hist_t *hs, const double *inc, const double *t_end, const double *dts,
                     size_t k0, const int64_t *end, const int64_t *ab, size_t ng, const double *bt, const double *alt,
                     double *out, double *pre, double *gate, double qtol, double vmax2, double hmin, double hmax,
                     size_t *groups, int *why);
size_t cref_run_gnss(ins_core_t *c, ins_hist_t *hs, const double *inc, const double *t_end, const double *dts,
                     size_t k0, const int64_t *end, const int64_t *ab, size_t ng, const double *fix, double vel_delay,
                     int check_vel, double *out, double *pre, double *gate, double qtol, double vmax2, double hmin,
                     double hmax, size_t *groups, int *why);
int cref_gfuse_mag(ins_core_t *c, ins_hist_t *hs, double t, double fx, double fy, double fz, double o[4]);
int cref_fuse_gnss(ins_core_t *c, double t, double lat, double lon, double h, const double vel[3], double std_ne,
                   double std_d, double std_vel);
int cref_fuse_baro(ins_core_t *c, double t, double altitude);
void ins_gsf_init(ins_gsf_t *g, int n);
void cref_gsf_predict(ins_gsf_t *g, const double dth[3], const double dv[3], double dt, double forward_speed);
void cref_gsf_fuse_vel(ins_gsf_t *g, const double vel_ne[2], double std);
void cref_mech_set(ins_mech_t *m, const double q[4], const double v[3], double lat, double lon, double h, double t,
                   const double dth_prev[3], const double dv_prev[3], int have_prev);
void cref_heading_run(ins_mech_t *m, ins_gsf_t *g, const double *inc, const double *t_end, const double *dts, size_t n,
                      const double bg[3], const double ba[3], double *out);
void ins_level_init(ins_level_t *l, double time, double still_delay, double frozen, double still_tau, double gyro2,
                    double accel2);
void ins_imu_check_init(ins_imu_check_t *c, double window);
int cref_level_step(ins_level_t *l, const double dth[3], const double dv[3], double dt, double t);
int cref_imu_check_add(ins_imu_check_t *c, const double dth[3], const double dv[3], double dt);
int cref_level_run(ins_level_t *l, ins_imu_check_t *chk, ins_gsf_t *g, const double bg[3], const double *inc,
                   const double *t_end, const double *dts, size_t n, size_t *done);
void cref_level_bring_forward(const ins_level_t *l, ins_mech_t *m, const double bg[3]);
int cref_fuse_gnss_repeat(ins_core_t *c, double lat, double lon, double h, const double vel[3], double std_ne,
                          double std_d, double std_vel, size_t n);
"""

#: headers whose declarations the cdef takes as they are (the header the one source of them)
_HEADERS = ["live.h"]  # live.c: the live gateway's per-sample path (the FDI parity group, ODOMETRY, MAVLink framing)

# firmware_ref/src/py_glue.c (a source file, so ensure_venv rebuilds) and the headers' declarations
_GLUE = '#include "py_glue.c"\n' + "".join(f'#include "{h}"\n' for h in _HEADERS)


def _declarations(header: str) -> str:
    """The C declarations of ``src/<header>`` for the cdef: the header without its preprocessor lines (include
    guard, includes, macros; cffi's cdef takes none of them but integer ``#define``s)."""
    out: list[str] = []
    directive = False
    for line in (_HERE / "src" / header).read_text().splitlines(keepends=True):
        directive = directive or line.lstrip().startswith("#")
        if not directive:
            out.append(line)
        directive = directive and line.rstrip().endswith("\\")  # a directive continued on the next line
    return "".join(out)


def _builder(module: str, real: str, defines: list[tuple[str, str | None]]) -> FFI:
    ffi = FFI()
    ffi.cdef(_CDEF.format(real=real) + "".join(_declarations(h) for h in _HEADERS))
    ffi.set_source(
        module,
        _GLUE,
        sources=[_rel(_HERE / "src" / s) for s in _SOURCES],
        include_dirs=[_rel(_HERE / "include"), _rel(_HERE / "src")],
        depends=[
            _rel(p)
            for p in (
                *(_HERE / "src").glob("*.[ch]"),
                *(_HERE / "src" / "generated").glob("*.h"),
                _HERE / "include" / "ins_ref.h",
            )
        ],
        define_macros=defines,
        # -fno-wrapv: Python's own CFLAGS (sysconfig) add -fwrapv, which keeps GCC from treating the int loop
        # counters as non-overflowing: 13 % more instructions than the Makefile's build (callgrind, ins_ref_bench
        # --hist 12000 10 20: 346M vs 307M; the same code built with and without it prints the same numbers, as
        # the C has no signed overflow)
        extra_compile_args=["-std=c99", "-O3", "-ffp-contract=off", "-fno-wrapv"],
        libraries=["m"],
    )
    return ffi


ffi_double = _builder("ins_hil._cref", "double", [])
ffi_float = _builder("ins_hil._cref_f32", "float", [("INS_REF_FLOAT", None)])

if __name__ == "__main__":
    ffi_double.compile(verbose=True)
    ffi_float.compile(verbose=True)
