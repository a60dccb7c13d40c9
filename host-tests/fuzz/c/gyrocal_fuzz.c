/* The GyroCal C loader on arbitrary flash pages: under libFuzzer
 *   clang -fsanitize=fuzzer,address,undefined -I calib-core/arduino/GyroCal/src \
 *     host-tests/fuzz/c/gyrocal_fuzz.c calib-core/arduino/GyroCal/src/gyrocal.c -lm
 * or, with -DGYROCAL_FUZZ_REPLAY and any C compiler, a main that replays corpus files
 * (tests/corpora.rs, built with -fsanitize=address,undefined).
 *
 * Input: a mode byte, then page A's bytes (page B: the same when bit 0 is set, else erased).
 * Bit 1 makes the record's CRC right (by its version byte's length) so that the fields'
 * checks are reached; bit 2 loads for the default setup. A loaded calibration is applied and
 * must give finite values; its status string is never NULL. */
#include "gyrocal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* CRC-32 (IEEE 802.3, reflected), as the record's. */
static uint32_t crc32(const uint8_t *p, size_t n) {
    uint32_t crc = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; i++) {
        crc ^= p[i];
        for (int k = 0; k < 8; k++) crc = (crc & 1u) ? (crc >> 1) ^ 0xEDB88320u : crc >> 1;
    }
    return ~crc;
}

static void check_finite(const float v[3]) {
    for (int i = 0; i < 3; i++)
        if (!isfinite(v[i])) abort();
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    static uint8_t region[GYROCAL_REGION_SIZE];
    /* Record lengths of versions 1..5 (calib-core's LEN_V1..LEN). */
    static const size_t len_of[6] = {320, 156, 188, 232, 236, 320};
    if (size == 0) return 0;
    uint8_t mode = data[0];
    data++;
    size--;
    memset(region, 0xFF, sizeof region);
    size_t n = size < GYROCAL_PAGE_SIZE ? size : GYROCAL_PAGE_SIZE;
    memcpy(region, data, n);
    if (mode & 2) {
        size_t len = (n > 4 && region[4] <= 5) ? len_of[region[4]] : len_of[0];
        if (n >= len) {
            uint32_t crc = crc32(region, len - 4);
            for (int i = 0; i < 4; i++) region[len - 4 + i] = (uint8_t)(crc >> (8 * i));
        }
    }
    if (mode & 1) memcpy(region + GYROCAL_PAGE_SIZE, region, GYROCAL_PAGE_SIZE);
    struct gyrocal cal;
    bool ok = (mode & 4) ? gyrocal_load_for(region, &GYROCAL_SETUP_DEFAULT, &cal) : gyrocal_load(region, &cal);
    if (gyrocal_status_str(cal.status) == NULL) abort();
    if (!ok) return 0;
    float raw[3] = {12.5f, -40.0f, 3.0f}, out[3];
    gyrocal_gyro_dps(&cal, raw, out);
    check_finite(out);
    gyrocal_accel_g(&cal, raw, out);
    check_finite(out);
    gyrocal_mag_ut(&cal, raw, out);
    check_finite(out);
    /* An offset refresh fed from the input's bytes. */
    struct gyrocal_mag_refresh f;
    gyrocal_mag_refresh_begin(&f);
    for (size_t i = 0; i + 3 <= n && i < 3 * 64; i += 3) {
        float m[3] = {(int8_t)data[i] * 0.5f, (int8_t)data[i + 1] * 0.5f, (int8_t)data[i + 2] * 0.5f};
        gyrocal_mag_refresh_add(&f, &cal, m);
    }
    if (gyrocal_mag_refresh_end(&f, &cal)) check_finite(cal.mag_offset_ut);
    return 0;
}

#ifdef GYROCAL_FUZZ_REPLAY
int main(int argc, char **argv) {
    static uint8_t buf[1 << 16];
    for (int i = 1; i < argc; i++) {
        FILE *f = fopen(argv[i], "rb");
        if (!f) {
            fprintf(stderr, "%s: cannot open\n", argv[i]);
            return 1;
        }
        size_t n = fread(buf, 1, sizeof buf, f);
        fclose(f);
        LLVMFuzzerTestOneInput(buf, n);
    }
    printf("replayed %d\n", argc - 1);
    return 0;
}
#endif
