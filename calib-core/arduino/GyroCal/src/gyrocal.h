/* GyroCal: load and apply the calibration the gyrocal firmware stored in flash.
 *
 * The firmware keeps its calibration record in two 4 KiB flash pages at 0xF8000 (A/B). The
 * Arduino bootloader erases only the pages a sketch upload writes, so the record survives the
 * upload of your own sketch, and this library finds it there: the newest valid record of the two
 * pages (magic, version, CRC-32 and every field checked, sequence numbers compared with
 * wrap-around), exactly as the firmware's own storage and calib_core::formats::region decide.
 *
 * Model and units (the same as the firmware and every export):
 *   gyro   out_dps = K (raw_dps - bias_dps)        K row-major, raw in the datasheet's units
 *   accel  out_g   = M (raw_g - offset_g)
 *   mag    out_ut  = A (raw_ut - offset_ut)   (record version 5 on: mag_known; else A = I)
 * "raw" is the sensor's counts times its datasheet sensitivity at the range the record was made
 * at (e.g. 70 mdps/LSB at +-2000 dps on the LSM9DS1, range/32768 per LSB on the BMI270, its
 * GYR_CAS trim NOT applied), in the BOARD FRAME (record version 6; docs/frames.md): right-handed,
 * x towards the USB connector, z out of the component side, the same on Rev1 and Rev2. Records
 * of versions 1-5 (the part's raw axes) are converted when loaded. The outputs are in the board
 * frame too. Pass each library's readings through its converter first:
 *   Arduino_LSM9DS1 (any version)            gyrocal_from_arduino_lsm9ds1(), ..._lsm9ds1_mag()
 *   Arduino_BMI270_BMM150 1.1.0 and later    gyrocal_from_arduino_bmi270(), ..._bmm150()
 *   Arduino_BMI270_BMM150 1.0.x              gyrocal_from_arduino_bmi270_v10(), ..._bmm150()
 *
 * A K holds for the configuration it was measured at (the gyro's sensitivity is trimmed per full
 * scale), so load with the configuration your program runs the sensor at: a record made at
 * another one is refused (GYROCAL_OTHER_SETUP), never applied. If the load fails, the struct
 * holds the identity (K = M = I, no bias, no offset) and the apply functions return their input.
 */
#ifndef GYROCAL_H
#define GYROCAL_H

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** Flash address of the two record pages on the Nano 33 BLE, and one page's size (bytes). */
#define GYROCAL_FLASH_ADDRESS 0xF8000u
#define GYROCAL_PAGE_SIZE 4096u
/** The region gyrocal_load() reads: both pages. */
#define GYROCAL_REGION_SIZE (2u * GYROCAL_PAGE_SIZE)

/** The part a calibration was made with. */
enum gyrocal_sensor {
    GYROCAL_LSM9DS1 = 0, /**< Nano 33 BLE (Rev1) */
    GYROCAL_BMI270 = 1   /**< Nano 33 BLE Rev2 */
};

/** The sensor configuration a calibration was made at. */
struct gyrocal_setup {
    float odr_hz;                /**< output data rate (Hz) */
    float gyro_range_dps;        /**< gyro full scale (dps) */
    float accel_range_g;         /**< accelerometer full scale (g) */
    enum gyrocal_sensor sensor;  /**< the part */
};

/** The firmware's default: LSM9DS1 at 119 Hz, +-500 dps, +-2 g. */
extern const struct gyrocal_setup GYROCAL_SETUP_DEFAULT;
/** What Arduino_LSM9DS1's IMU.begin() sets (CTRL_REG1_G 0x78, CTRL_REG6_XL 0x70): 119 Hz,
 *  +-2000 dps, +-4 g. The firmware calibrates at it when built with `--features arduino-lsm9ds1`
 *  or after the console command `p`. */
extern const struct gyrocal_setup GYROCAL_SETUP_ARDUINO_LSM9DS1;
/** The Rev2 firmware's own: BMI270 at 100 Hz, +-500 dps, +-2 g. */
extern const struct gyrocal_setup GYROCAL_SETUP_BMI270_DEFAULT;
/** What Arduino_BMI270_BMM150's IMU.begin() sets: BMI270 at 100 Hz, +-2000 dps, +-4 g. The
 *  firmware calibrates a Rev2 at it after the console command `p`. */
extern const struct gyrocal_setup GYROCAL_SETUP_ARDUINO_BMI270;

/** Why a load gave no calibration. */
enum gyrocal_status {
    GYROCAL_OK = 0,       /**< a valid record was loaded */
    GYROCAL_NO_RECORD,    /**< neither page holds a valid record (erased, or overwritten by a
                               sketch's own use of that flash) */
    GYROCAL_OTHER_SETUP   /**< the newest record was made at another configuration */
};

/** A loaded calibration. */
struct gyrocal {
    enum gyrocal_status status;
    uint32_t seq;               /**< the record's sequence number */
    uint8_t page;               /**< which page it came from (0 = A at 0xF8000, 1 = B) */
    uint8_t version;            /**< record format version (1..6; 1..5 converted to the board frame) */
    uint8_t method;             /**< gyro estimator: 0 paper, 1 sweep, 2 full 3x3 K */
    struct gyrocal_setup setup; /**< the configuration it was made at */
    int8_t gyr_cas;             /**< a BMI270's GYR_CAS (z to x trim, per 512), 0 for an LSM9DS1 */
    bool user_gain;             /**< a BMI270's gyro user gain (CRT) was on when it was made */
    float gyro_k[3][3];         /**< K, row-major (unitless) */
    float gyro_bias_dps[3];     /**< gyro bias (dps) at temp_c */
    float accel_m[3][3];        /**< M, row-major (unitless) */
    float accel_offset_g[3];    /**< accelerometer offset (g) */
    bool temp_known;            /**< temp_c holds the temperature K and the bias were made at */
    float temp_c;               /**< (degC) */
    bool tempco_known;          /**< tempco_dps_per_c holds the bias's temperature coefficient */
    float tempco_dps_per_c[3];  /**< bias(T) = bias + tempco (T - temp_c) (dps per degC) */
    bool mag_known;             /**< the record holds a magnetometer calibration (version 5) */
    float mag_a[3][3];          /**< A, row-major: soft iron, scale and the die's alignment onto
                                     the calibrated accelerometer (unitless; I when unknown) */
    float mag_offset_ut[3];     /**< hard iron and the part's offset (uT, its raw frame) */
    float mag_field_ut;         /**< the field strength at calibration (uT; 0 when unknown) */
    float mag_dip_deg;          /**< its dip below the horizon (deg; 0 when unknown) */
};

/** Loads the newest valid record of `region` (GYROCAL_REGION_SIZE bytes: page A then page B),
 *  whatever configuration it was made at. Returns true when one was found. */
bool gyrocal_load(const void *region, struct gyrocal *cal);

/** gyrocal_load(), refusing a record made at another configuration than `runs_at`. */
bool gyrocal_load_for(const void *region, const struct gyrocal_setup *runs_at, struct gyrocal *cal);

/** gyrocal_load() / gyrocal_load_for() of the pages in this board's flash at 0xF8000 (the
 *  nRF52840's flash is memory-mapped). On any other target they return false, GYROCAL_NO_RECORD. */
bool gyrocal_load_flash(struct gyrocal *cal);
bool gyrocal_load_flash_for(const struct gyrocal_setup *runs_at, struct gyrocal *cal);

/** Calibrated rate out = K (raw - bias) (dps); `raw_dps` and `out_dps` may be the same array. */
void gyrocal_gyro_dps(const struct gyrocal *cal, const float raw_dps[3], float out_dps[3]);

/** Calibrated specific force out = M (raw - offset) (g); `raw_g` and `out_g` may be the same. */
void gyrocal_accel_g(const struct gyrocal *cal, const float raw_g[3], float out_g[3]);

/** Calibrated field out = A (raw - offset) (uT), in the calibrated accelerometer's frame (the
 *  frame of K and M); `raw_ut` in the board frame: on a Rev1 pass Arduino_LSM9DS1's
 *  readMagneticField() through gyrocal_from_arduino_lsm9ds1_mag() first, on a Rev2
 *  Arduino_BMI270_BMM150's readMagneticField() through gyrocal_from_arduino_bmm150(). The identity
 *  when the record has no magnetometer calibration (mag_known false). */
void gyrocal_mag_ut(const struct gyrocal *cal, const float raw_ut[3], float out_ut[3]);

/** Arduino_LSM9DS1's readMagneticField() (counts * 400/32768 uT, the magnetometer's own axes,
 *  which are the board frame's) in uT at the datasheet's 0.14 mgauss/LSB (+-4 gauss: the library
 *  reads 13 % low). In place. */
void gyrocal_from_arduino_lsm9ds1_mag(float mag_ut[3]);

/** Arduino_BMI270_BMM150's readMagneticField() (the BMM150's own axes, never remapped) in the
 *  board frame: (-y, -x, -z), a turn of 180 deg about x from the BMI270's axes (UNVERIFIED on a
 *  board: docs/frames.md). In place. */
void gyrocal_from_arduino_bmm150(float mag_ut[3]);

/** An in-sketch refresh of the magnetometer's offset (hard iron) for the robot the board is
 *  built into, which adds its own: A (soft iron and the die's alignment) is kept, the offset
 *  refitted from readings spread over a tumble (turn the robot through as many orientations as
 *  it allows; at least GYROCAL_MAG_REFRESH_MIN readings). O(1) memory: no readings are kept. */
struct gyrocal_mag_refresh {
    double n[4][4];      /**< normal equations of |A (m - o)|^2 = B^2, linear in A o and B */
    double r[4];
    double yy;
    uint32_t count;      /**< readings added */
    float field_ut;      /**< after gyrocal_mag_refresh_end(): the field strength fitted (uT) */
    float residual_ut;   /**< ... and the RMS of |m| - field over the readings (uT) */
    float moved_ut;      /**< ... and how far the offset moved (uT) */
};

/** Readings a refresh needs at least. */
#define GYROCAL_MAG_REFRESH_MIN 50u

/** Starts a refresh (clears `f`). */
void gyrocal_mag_refresh_begin(struct gyrocal_mag_refresh *f);

/** Adds a raw reading (uT, the accelerometer's axes: as gyrocal_mag_ut() takes it). */
void gyrocal_mag_refresh_add(struct gyrocal_mag_refresh *f, const struct gyrocal *cal, const float raw_ut[3]);

/** Fits the offset and, when the fit is determined (enough readings spread over more than a
 *  plane, a record with a magnetometer calibration), writes it into `cal->mag_offset_ut` and
 *  returns true; `f` then holds the fit's figures. False leaves `cal` as it was. */
bool gyrocal_mag_refresh_end(struct gyrocal_mag_refresh *f, struct gyrocal *cal);

/** The record's status as a sentence. */
const char *gyrocal_status_str(enum gyrocal_status status);

/** Arduino_LSM9DS1's readGyroscope() (counts * 2000/32768) and readAcceleration() (counts * 4/32768)
 *  in the datasheet's units at its +-2000 dps / +-4 g (70 mdps and 0.122 mg per LSB: the library's
 *  gyro reads 12.8 % low) and in the board frame: (-x, y, z) of the LSM9DS1's raw axes, which
 *  form a left-handed triad. Either pointer may be NULL; arrays are converted in place. */
void gyrocal_from_arduino_lsm9ds1(float gyro_dps[3], float accel_g[3]);

/** Arduino_BMI270_BMM150 (1.1.0 and later)'s readGyroscope() and readAcceleration() (its units
 *  are the datasheet's: counts * range/32768) in the board frame: its remap x = -y, y = -x undone,
 *  the GYR_CAS it applied (x - cas z / 512) undone with the record's `cal->gyr_cas`, then (y, -x,
 *  z) of Bosch's axes. Either pointer may be NULL; arrays are converted in place. */
void gyrocal_from_arduino_bmi270(const struct gyrocal *cal, float gyro_dps[3], float accel_g[3]);

/** The same for Arduino_BMI270_BMM150 1.0.x, which returns Bosch's axes (no remap). */
void gyrocal_from_arduino_bmi270_v10(const struct gyrocal *cal, float gyro_dps[3], float accel_g[3]);

#ifdef __cplusplus
}
#endif

#endif /* GYROCAL_H */
