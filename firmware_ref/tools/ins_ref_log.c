/* ins_ref_log: run the reference core over a binary IMU log in the ins_hil
 * serial frame format (drivers/SERIAL_FRAME.md) and write the states as CSV,
 * as flight firmware on a bench would.
 *
 *   ins_ref_log [options] LOG.bin > states.csv     (LOG "-" = stdin)
 *     --lat DEG --lon DEG --h M       initial position (default 0 0 0)
 *     --rpy R,P,Y                     initial roll,pitch,yaw in deg (default 0,0,0)
 *     --vel N,E,D                     initial NED velocity m/s (default 0,0,0)
 *     --dt S                          fixed step (default: the first frame's dt_us)
 *     --imu ID                        use frames of this imu_id only (default: the first seen)
 *     --every N                       write every N-th state (default 1)
 *     --filter                        run the EKF predict too (std columns become meaningful)
 * Frames failing sync/version/CRC are skipped byte-wise (as the Python FrameParser);
 * counters go to stderr. CSV: t,q0,q1,q2,q3,vN,vE,vD,lat,lon,h (rad, m, m/s, s). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ins_ref.h"

static int parse3(const char *s, double v[3]) { return sscanf(s, "%lf,%lf,%lf", &v[0], &v[1], &v[2]) == 3 ? 0 : -1; }

static int usage(const char *msg, const char *arg) {
    fprintf(stderr, "ins_ref_log: %s%s%s\n", msg, arg ? ": " : "", arg ? arg : "");
    fprintf(stderr, "usage: ins_ref_log [--lat DEG --lon DEG --h M --rpy R,P,Y --vel N,E,D --dt S --imu ID "
                    "--every N --filter] LOG.bin\n");
    return 2;
}

int main(int argc, char **argv) {
    const double d2r = 3.14159265358979323846 / 180.0;
    double lat = 0, lon = 0, h = 0, rpy[3] = {0, 0, 0}, vel[3] = {0, 0, 0}, dt = 0;
    long every = 1, imu = -1;
    int filter = 0, i, started = 0;
    const char *path = NULL;
    FILE *in;
    static uint8_t buf[65536];
    size_t have = 0, pos = 0;
    unsigned long n_ok = 0, n_bad = 0, n_other = 0, n_dt = 0;
    unsigned long long t_hi = 0;
    uint32_t t_last = 0;
    ins_core_t core;

    for (i = 1; i < argc; ++i) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        char *end = NULL;
        if (strcmp(a, "--filter") == 0) {
            filter = 1;
            continue;
        }
        if (a[0] == '-' && a[1] == '-') {
            if (v == NULL) return usage("missing value for", a);
            errno = 0;
            if (strcmp(a, "--lat") == 0) lat = strtod(v, &end) * d2r;
            else if (strcmp(a, "--lon") == 0) lon = strtod(v, &end) * d2r;
            else if (strcmp(a, "--h") == 0) h = strtod(v, &end);
            else if (strcmp(a, "--dt") == 0) dt = strtod(v, &end);
            else if (strcmp(a, "--every") == 0) every = strtol(v, &end, 10);
            else if (strcmp(a, "--imu") == 0) imu = strtol(v, &end, 10);
            else if (strcmp(a, "--rpy") == 0) { if (parse3(v, rpy)) return usage("bad --rpy (want R,P,Y)", v); end = NULL; }
            else if (strcmp(a, "--vel") == 0) { if (parse3(v, vel)) return usage("bad --vel (want N,E,D)", v); end = NULL; }
            else return usage("unknown option", a);
            if (end != NULL && (*end != '\0' || end == v || errno)) return usage("bad number", v);
            ++i;
            continue;
        }
        if (path != NULL) return usage("more than one log file", a);
        path = a;
    }
    if (path == NULL) return usage("no log file given", NULL);
    if (every < 1) return usage("--every must be >= 1", NULL);
    if (dt < 0) return usage("--dt must be positive", NULL);
    in = strcmp(path, "-") == 0 ? stdin : fopen(path, "rb");
    if (in == NULL) {
        fprintf(stderr, "ins_ref_log: cannot open %s: %s\n", path, strerror(errno));
        return 1;
    }
    printf("t,q0,q1,q2,q3,vN,vE,vD,lat,lon,h\n");
    for (;;) {
        size_t got;
        if (pos > 0) { /* keep the unparsed tail */
            memmove(buf, buf + pos, have - pos);
            have -= pos;
            pos = 0;
        }
        got = fread(buf + have, 1, sizeof buf - have, in);
        have += got;
        if (have - pos < INS_FRAME_LEN && got == 0) break;
        while (have - pos >= INS_FRAME_LEN) {
            ins_frame_t f;
            if (ins_frame_decode(buf + pos, &f) != 0) {
                if (buf[pos] == 0xA5 && pos + 1 < have && buf[pos + 1] == 0x5A) n_bad++;
                pos++;
                continue;
            }
            pos += INS_FRAME_LEN;
            if (imu < 0) imu = f.imu_id;
            if (f.imu_id != imu) {
                n_other++;
                continue;
            }
            if (!started) {
                ins_real q[4], r[3], v[3];
                int k;
                for (k = 0; k < 3; ++k) {
                    r[k] = (ins_real)(rpy[k] * d2r);
                    v[k] = (ins_real)vel[k];
                }
                ins_quat_from_euler(r, q);
                if (dt == 0) dt = f.dt_us * 1e-6;
                t_last = f.t_us;
                ins_core_init(&core, q, v, lat, lon, h, (f.t_us - f.dt_us) * 1e-6, (ins_real)dt, NULL, filter);
                started = 1;
            }
            if (f.t_us < t_last) t_hi += 1ULL << 32; /* unwrap the 32-bit microsecond clock */
            t_last = f.t_us;
            if (fabs(f.dt_us * 1e-6 - dt) > 0.05 * dt) n_dt++;
            {
                ins_real a[3], u[3];
                int k;
                for (k = 0; k < 3; ++k) {
                    a[k] = (ins_real)f.dtheta[k];
                    u[k] = (ins_real)f.dvel[k];
                }
                ins_core_step(&core, a, u, (double)(t_hi + f.t_us) * 1e-6);
            }
            n_ok++;
            if (n_ok % (unsigned long)every == 0) {
                ins_out_t o;
                ins_core_output(&core, &o);
                printf("%.9f,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g\n", o.t, (double)o.q[0],
                       (double)o.q[1], (double)o.q[2], (double)o.q[3], (double)o.v[0], (double)o.v[1], (double)o.v[2],
                       o.lat, o.lon, o.h);
            }
        }
    }
    if (in != stdin) fclose(in);
    fprintf(stderr, "ins_ref_log: %lu frames used, %lu bad frames skipped, %lu of other IMUs, %lu off the fixed step\n",
            n_ok, n_bad, n_other, n_dt);
    return n_ok > 0 ? 0 : 1;
}
