/* The GyroCal Arduino library on the host, for tests/arduino.rs.
 * gyrocal_check REGION [ODR GYRO_RANGE ACCEL_RANGE SENSOR]: loads the 8 KiB region (with the
 * setup, SENSOR 0 LSM9DS1 or 1 BMI270: as gyrocal_load_for) and prints what it loaded; then each
 * stdin line `raw g0 g1 g2 a0 a1 a2` (datasheet units), `lib ...` (Arduino_LSM9DS1's readings) or
 * `bmi ...` (Arduino_BMI270_BMM150's) is printed calibrated. */
#include "gyrocal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void floats(const char *name, const float *v, int n) {
    printf("%s", name);
    for (int i = 0; i < n; i++) {
        printf(" %.9g", (double)v[i]);
    }
    printf("\n");
}

int main(int argc, char **argv) {
    static unsigned char region[GYROCAL_REGION_SIZE + 1];
    struct gyrocal cal;
    bool ok;
    if (argc != 2 && argc != 6) {
        fprintf(stderr, "usage: gyrocal_check REGION [ODR GYRO_RANGE ACCEL_RANGE SENSOR]\n");
        return 2;
    }
    FILE *f = fopen(argv[1], "rb");
    if (!f || fread(region, 1, sizeof region, f) != GYROCAL_REGION_SIZE) {
        fprintf(stderr, "%s: not an 8 KiB region\n", argv[1]);
        return 2;
    }
    fclose(f);
    if (argc == 6) {
        struct gyrocal_setup s = {strtof(argv[2], NULL), strtof(argv[3], NULL), strtof(argv[4], NULL),
                                  atoi(argv[5]) == 1 ? GYROCAL_BMI270 : GYROCAL_LSM9DS1};
        ok = gyrocal_load_for(region, &s, &cal);
    } else {
        ok = gyrocal_load(region, &cal);
    }
    printf("ok %d status %d seq %lu page %u version %u method %u\n", ok, (int)cal.status, (unsigned long)cal.seq, cal.page,
           cal.version, cal.method);
    printf("says %s\n", gyrocal_status_str(cal.status));
    floats("setup", &cal.setup.odr_hz, 1);
    floats("gyro_range", &cal.setup.gyro_range_dps, 1);
    floats("accel_range", &cal.setup.accel_range_g, 1);
    printf("sensor %d\n", (int)cal.setup.sensor);
    printf("gyr_cas %d\n", (int)cal.gyr_cas);
    printf("user_gain %d\n", cal.user_gain);
    printf("temp_known %d\n", cal.temp_known);
    floats("temp", &cal.temp_c, 1);
    printf("tempco_known %d\n", cal.tempco_known);
    floats("tempco", cal.tempco_dps_per_c, 3);
    floats("k", &cal.gyro_k[0][0], 9);
    floats("bias", cal.gyro_bias_dps, 3);
    floats("m", &cal.accel_m[0][0], 9);
    floats("offset", cal.accel_offset_g, 3);
    char kind[8];
    float in[6];
    while (scanf("%7s %f %f %f %f %f %f", kind, &in[0], &in[1], &in[2], &in[3], &in[4], &in[5]) == 7) {
        if (strcmp(kind, "lib") == 0) {
            gyrocal_from_arduino_lsm9ds1(in, in + 3);
        } else if (strcmp(kind, "bmi") == 0) {
            gyrocal_from_arduino_bmi270(&cal, in, in + 3);
        }
        gyrocal_gyro_dps(&cal, in, in);
        gyrocal_accel_g(&cal, in + 3, in + 3);
        floats("out", in, 6);
    }
    return 0;
}
