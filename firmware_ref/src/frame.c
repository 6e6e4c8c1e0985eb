/* ins_hil serial IMU frame v1 decoder (drivers/SERIAL_FRAME.md). */
#include <string.h>

#include "ins_ref.h"

uint16_t ins_crc16_ccitt(const uint8_t *data, size_t n, uint16_t init) {
    /* CRC-16/CCITT-FALSE: poly 0x1021, no reflection */
    uint16_t crc = init;
    size_t i;
    int b;
    for (i = 0; i < n; ++i) {
        crc = (uint16_t)(crc ^ (uint16_t)(data[i] << 8));
        for (b = 0; b < 8; ++b) crc = (uint16_t)((crc & 0x8000u) ? ((unsigned)(crc << 1) ^ 0x1021u) : (unsigned)(crc << 1));
    }
    return crc;
}

static uint16_t rd16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static uint32_t rd32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static float rdf(const uint8_t *p) {
    const uint32_t u = rd32(p);
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

int ins_frame_decode(const uint8_t *buf, ins_frame_t *f) {
    int i;
    if (buf[0] != 0xA5 || buf[1] != 0x5A) return -1;
    if (buf[2] != 1) return -2;
    if (ins_crc16_ccitt(buf + 2, 37, 0xFFFF) != rd16(buf + 39)) return -3;
    f->imu_id = buf[3];
    f->seq = rd16(buf + 4);
    f->t_us = rd32(buf + 6);
    f->dt_us = rd16(buf + 10);
    for (i = 0; i < 3; ++i) {
        f->dtheta[i] = rdf(buf + 12 + 4 * i);
        f->dvel[i] = rdf(buf + 24 + 4 * i);
    }
    f->temp_cdeg = (int16_t)rd16(buf + 36);
    f->flags = buf[38];
    return 0;
}
