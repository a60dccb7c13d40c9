/* The GyroCal Arduino library on the host, for tests/arduino.rs.
 * gyrocal_check REGION [ODR GYRO_RANGE ACCEL_RANGE SENSOR]: loads the 8 KiB region (with the
 * setup, SENSOR 0 LSM9DS1 or 1 BMI270: as gyrocal_load_for) and prints what it loaded; then each
 * stdin line `raw g0 g1 g2 a0 a1 a2` (datasheet units), `lib ...` (Arduino_LSM9DS1's readings) or
 * `bmi ...` (Arduino_BMI270_BMM150's) is printed calibrated; `mag m0 m1 m2 0 0 0` (uT) and `lmag ...`
 * (Arduino_LSM9DS1's readMagneticField()) print `mag_out` through gyrocal_mag_ut(); `tumble m0 m1 m2
 * 0 0 0` adds a reading to an offset refresh and `refresh 0 0 0 0 0 0` ends it, printing `refreshed
 * OK FIELD RESIDUAL MOVED O0 O1 O2`. */
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
    printf("mag_known %d\n", cal.mag_known);
    floats("mag_a", &cal.mag_a[0][0], 9);
    floats("mag_offset", cal.mag_offset_ut, 3);
    floats("mag_field", &cal.mag_field_ut, 1);
    floats("mag_dip", &cal.mag_dip_deg, 1);
    char kind[8];
    float in[6];
    struct gyrocal_mag_refresh refresh;
    gyrocal_mag_refresh_begin(&refresh);
    while (scanf("%7s %f %f %f %f %f %f", kind, &in[0], &in[1], &in[2], &in[3], &in[4], &in[5]) == 7) {
        if (strcmp(kind, "mag") == 0 || strcmp(kind, "lmag") == 0 || strcmp(kind, "bmm") == 0) {
            if (kind[0] == 'l') {
                gyrocal_from_arduino_lsm9ds1_mag(in);
            } else if (kind[0] == 'b') {
                gyrocal_from_arduino_bmm150(in);
            }
            gyrocal_mag_ut(&cal, in, in);
            floats("mag_out", in, 3);
            continue;
        }
        if (strcmp(kind, "tumble") == 0) {
            gyrocal_mag_refresh_add(&refresh, &cal, in);
            continue;
        }
        if (strcmp(kind, "refresh") == 0) {
            bool done = gyrocal_mag_refresh_end(&refresh, &cal);
            printf("refreshed %d %.9g %.9g %.9g %.9g %.9g %.9g\n", done, (double)refresh.field_ut, (double)refresh.residual_ut,
                   (double)refresh.moved_ut, (double)cal.mag_offset_ut[0], (double)cal.mag_offset_ut[1], (double)cal.mag_offset_ut[2]);
            gyrocal_mag_refresh_begin(&refresh);
            continue;
        }
        if (strcmp(kind, "lib") == 0) {
            gyrocal_from_arduino_lsm9ds1(in, in + 3);
        } else if (strcmp(kind, "bmi") == 0) {
            gyrocal_from_arduino_bmi270(&cal, in, in + 3);
        } else if (strcmp(kind, "bmi10") == 0) {
            gyrocal_from_arduino_bmi270_v10(&cal, in, in + 3);
        }
        gyrocal_gyro_dps(&cal, in, in);
        gyrocal_accel_g(&cal, in + 3, in + 3);
        floats("out", in, 6);
    }
    return 0;
}
