/* The live gateway's per-sample path in C (live.c; the Python extension only). */
#ifndef LIVE_H
#define LIVE_H
#include <stddef.h>
#include <stdint.h>

#define LIVE_FDI_MAX_ROWS 16

/* One FDI parity group's state (ins_hil.fdi.monitor._Group), the arrays those of the Python object (shared):
 * n rows, nh healthy ones (their indices hidx), m = nh - 3 parity dimensions; M (m + 3) x nh = [V; Z], Un nh x m,
 * score nh, the history ring buf L x n and tbuf L at pos. */
typedef struct {
    int n, nh, m, L, pos, persistence;
    int *hidx;
    long long run, srun;
    double alpha, oma, thr_fast, thr_slow, onset;
    double *M, *Un, *prev, *buf, *tbuf, *ema, *score;
} live_fdi_group_t;

int live_fdi_step(live_fdi_group_t *g, double t, const double *y, double *est);
uint16_t live_crc(const uint8_t *p, size_t n, uint16_t crc);
size_t live_frame(uint8_t *out, const uint8_t *payload, size_t len, uint32_t msgid, uint8_t crc_extra, uint8_t seq,
                  uint8_t sysid, uint8_t compid);
int live_odometry(uint8_t *out, const double *s, const double *home, double *prev, int reset, const int *ids);
double live_hypot(double a, double b);
#endif
