/* GyroCal: the record layout of calib-core's record.rs (versions 1-6) and the page choice of its
 * region.rs, in C99 with no heap and no libm. See gyrocal.h. */
#include "gyrocal.h"

#include <stddef.h>
#include <string.h>

const struct gyrocal_setup GYROCAL_SETUP_DEFAULT = {119.0f, 500.0f, 2.0f, GYROCAL_LSM9DS1};
const struct gyrocal_setup GYROCAL_SETUP_ARDUINO_LSM9DS1 = {119.0f, 2000.0f, 4.0f, GYROCAL_LSM9DS1};
const struct gyrocal_setup GYROCAL_SETUP_BMI270_DEFAULT = {100.0f, 500.0f, 2.0f, GYROCAL_BMI270};
const struct gyrocal_setup GYROCAL_SETUP_ARDUINO_BMI270 = {100.0f, 2000.0f, 4.0f, GYROCAL_BMI270};

/* Record lengths (bytes) by version; the CRC-32 is the last 4 bytes. */
#define LEN_V1 156u
#define LEN_V2 188u
#define LEN_V3 232u
#define LEN_V4 236u
#define LEN_V5 320u
/* Flags: bit 0 the temperature is unknown, bit 1 (v3) the tempco is unknown, bit 2 (v5) there is
 * no magnetometer calibration. */
#define TEMP_UNKNOWN 1u
#define TEMPCO_UNKNOWN 2u
#define MAG_UNKNOWN 4u

/* The board frame (docs/frames.md, calib-core's board.rs): out[i] = sign[i] * in[from[i]]. */
struct axis_map {
    uint8_t from[3];
    int8_t sign[3];
};
static const struct axis_map LSM9DS1_AG = {{0, 1, 2}, {-1, 1, 1}};
static const struct axis_map BMI270 = {{1, 0, 2}, {1, -1, 1}};
static const struct axis_map BMM150 = {{1, 0, 2}, {-1, -1, -1}};

static void map_vec(const struct axis_map *p, float v[3]) {
    float in[3] = {v[0], v[1], v[2]};
    for (int i = 0; i < 3; i++) {
        v[i] = p->sign[i] * in[p->from[i]];
    }
}

/* m <- P m Q^T: element (i, j) is sign_i sign_j m[from_i][from_j]. */
static void map_mat(const struct axis_map *p, const struct axis_map *q, float m[3][3]) {
    float in[3][3];
    memcpy(in, m, sizeof in);
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++) {
            m[i][j] = p->sign[i] * q->sign[j] * in[p->from[i]][q->from[j]];
        }
    }
}

/* A record of versions 1-5 (the part's raw axes) in the board frame, as calib-core's
 * Record::from_part_axes: K' = P K P^T, b' = P b, M and o alike, the tempco P c; the
 * magnetometer's A' = P A Q^T, o' = Q o with Q its old input frame's map (the LSM9DS1's
 * accelerometer axes; the BMM150's own, taken as the BMI270's). */
static void from_part_axes(struct gyrocal *cal) {
    const struct axis_map *p = cal->setup.sensor == GYROCAL_BMI270 ? &BMI270 : &LSM9DS1_AG;
    const struct axis_map *q = cal->setup.sensor == GYROCAL_BMI270 ? &BMM150 : &LSM9DS1_AG;
    map_mat(p, p, cal->gyro_k);
    map_vec(p, cal->gyro_bias_dps);
    map_mat(p, p, cal->accel_m);
    map_vec(p, cal->accel_offset_g);
    map_vec(p, cal->tempco_dps_per_c);
    if (cal->mag_known) {
        map_mat(p, q, cal->mag_a);
        map_vec(q, cal->mag_offset_ut);
    }
}

/* CRC-32 (IEEE 802.3, reflected, init and final XOR 0xFFFFFFFF), bitwise. */
static uint32_t crc32(const uint8_t *p, size_t n) {
    uint32_t crc = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; i++) {
        crc ^= p[i];
        for (int b = 0; b < 8; b++) {
            crc = (crc & 1u) ? (crc >> 1) ^ 0xEDB88320u : crc >> 1;
        }
    }
    return ~crc;
}

static uint32_t u32_le(const uint8_t *p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* Reads little-endian f32s in order, noting any NaN or infinity. */
struct reader {
    const uint8_t *p;
    bool finite;
};

static float next_f32(struct reader *r) {
    uint32_t bits = u32_le(r->p);
    float v;
    r->p += 4;
    if ((bits & 0x7F800000u) == 0x7F800000u) {
        r->finite = false;
    }
    memcpy(&v, &bits, sizeof v);
    return v;
}

static void next_f32s(struct reader *r, float *out, int n) {
    for (int i = 0; i < n; i++) {
        out[i] = next_f32(r);
    }
}

static void identity(struct gyrocal *cal, enum gyrocal_status status) {
    memset(cal, 0, sizeof *cal);
    cal->status = status;
    for (int i = 0; i < 3; i++) {
        cal->gyro_k[i][i] = 1.0f;
        cal->accel_m[i][i] = 1.0f;
        cal->mag_a[i][i] = 1.0f;
    }
}

static bool within(const float *v, int n, float limit) {
    for (int i = 0; i < n; i++) {
        if (!(v[i] <= limit && v[i] >= -limit)) {
            return false;
        }
    }
    return true;
}

static bool near_identity(const float m[3][3]) {
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++) {
            float d = m[i][j] - (i == j ? 1.0f : 0.0f);
            if (!(d <= 0.5f && d >= -0.5f)) {
                return false;
            }
        }
    }
    return true;
}

/* The fields applied to readings within what a part can have, as calib-core's
 * Record::plausible: readings within a full scale then stay finite through every correction. */
static bool plausible(const struct gyrocal *cal) {
    const struct gyrocal_setup *s = &cal->setup;
    return near_identity(cal->gyro_k) && near_identity(cal->accel_m) && within(cal->gyro_bias_dps, 3, 4000.0f) &&
           within(cal->accel_offset_g, 3, 32.0f) && (!cal->temp_known || (cal->temp_c >= -60.0f && cal->temp_c <= 150.0f)) &&
           (!cal->tempco_known || within(cal->tempco_dps_per_c, 3, 1.0f)) &&
           (!cal->mag_known || (within(&cal->mag_a[0][0], 9, 10.0f) && within(cal->mag_offset_ut, 3, 5000.0f))) &&
           s->odr_hz > 0.0f && s->odr_hz <= 10000.0f && s->gyro_range_dps > 0.0f && s->gyro_range_dps <= 4000.0f &&
           s->accel_range_g > 0.0f && s->accel_range_g <= 32.0f;
}

/* Decodes one page into `cal`; false when it holds no valid record. */
static bool decode(const uint8_t *b, struct gyrocal *cal) {
    static const uint8_t magic[4] = {'G', 'Y', 'R', 'C'};
    uint32_t len;
    if (memcmp(b, magic, 4) != 0) {
        return false;
    }
    switch (b[4]) {
    case 1: len = LEN_V1; break;
    case 2: len = LEN_V2; break;
    case 3: len = LEN_V3; break;
    case 4: len = LEN_V4; break;
    case 5:
    case 6: len = LEN_V5; break;
    default: return false;
    }
    if (u32_le(b + len - 4) != crc32(b, len - 4) || b[5] > 2 || b[6] > 2) {
        return false;
    }
    uint16_t flags = (uint16_t)(b[14] | b[15] << 8);
    uint16_t known = len == LEN_V5 ? (TEMP_UNKNOWN | TEMPCO_UNKNOWN | MAG_UNKNOWN)
                     : len >= LEN_V3 ? (TEMP_UNKNOWN | TEMPCO_UNKNOWN)
                                     : TEMP_UNKNOWN;
    if (flags & ~known) {
        return false;
    }
    identity(cal, GYROCAL_OK);
    cal->version = b[4];
    cal->method = b[5];
    cal->seq = u32_le(b + 8);
    struct reader r = {b + 16, true};
    cal->temp_c = next_f32(&r);
    cal->temp_known = !(flags & TEMP_UNKNOWN);
    next_f32s(&r, &cal->gyro_k[0][0], 9);
    next_f32s(&r, cal->gyro_bias_dps, 3);
    next_f32s(&r, &cal->accel_m[0][0], 9);
    next_f32s(&r, cal->accel_offset_g, 3);
    /* 1 sigma of K (v1: its diagonal), the six quality fields, (v2+) residual and coplanarity:
     * not kept, but checked finite as the firmware does. */
    float skip[9];
    next_f32s(&r, skip, len == LEN_V1 ? 3 : 9);
    next_f32s(&r, skip, 6);
    cal->setup = GYROCAL_SETUP_DEFAULT;
    if (len >= LEN_V2) {
        next_f32s(&r, skip, 2);
    }
    if (len >= LEN_V3) {
        cal->setup.odr_hz = next_f32(&r);
        cal->setup.gyro_range_dps = next_f32(&r);
        cal->setup.accel_range_g = next_f32(&r);
        next_f32s(&r, cal->tempco_dps_per_c, 3);
        next_f32s(&r, skip, 5); /* its 1 sigma and the fitted temperature range */
        cal->tempco_known = !(flags & TEMPCO_UNKNOWN);
        if (!cal->tempco_known) {
            memset(cal->tempco_dps_per_c, 0, sizeof cal->tempco_dps_per_c);
        }
    }
    if (len >= LEN_V4) {
        /* The part, GYR_CAS (7-bit range), flags (bit 0 user gain), a reserved 0. */
        const uint8_t *p = b + LEN_V3 - 4;
        int8_t cas = (int8_t)p[1];
        if (p[0] == 0 && p[1] == 0 && p[2] == 0 && p[3] == 0) {
            cal->setup.sensor = GYROCAL_LSM9DS1;
        } else if (p[0] == 1 && cas >= -64 && cas <= 63 && (p[2] & ~1u) == 0 && p[3] == 0) {
            cal->setup.sensor = GYROCAL_BMI270;
            cal->gyr_cas = cas;
            cal->user_gain = p[2] == 1;
        } else {
            return false;
        }
        r.p = b + LEN_V4 - 4;
    }
    if (len == LEN_V5) {
        /* The magnetometer: A, offset (uT), field (uT), its 1 sigma, dip, its 1 sigma, alignment,
         * its 1 sigma, residual, coverage, then samples (u16), poses, a reserved 0. Zeros when
         * there is none. */
        float q[8];
        next_f32s(&r, &cal->mag_a[0][0], 9);
        next_f32s(&r, cal->mag_offset_ut, 3);
        next_f32s(&r, q, 8);
        const uint8_t *p = b + LEN_V5 - 8;
        if (p[3] != 0) {
            return false;
        }
        cal->mag_known = !(flags & MAG_UNKNOWN);
        if (cal->mag_known) {
            cal->mag_field_ut = q[0];
            cal->mag_dip_deg = q[2];
        } else {
            const uint8_t *z = b + LEN_V4 - 4;
            for (uint32_t i = 0; i < LEN_V5 - LEN_V4; i++) {
                if (z[i] != 0) {
                    return false;
                }
            }
            memset(cal->mag_a, 0, sizeof cal->mag_a);
            for (int i = 0; i < 3; i++) {
                cal->mag_a[i][i] = 1.0f;
            }
        }
    }
    if (cal->version < 6) {
        from_part_axes(cal);
    }
    return r.finite && plausible(cal);
}

static bool erased(const uint8_t *b) {
    for (uint32_t i = 0; i < LEN_V5; i++) {
        if (b[i] != 0xFF) {
            return false;
        }
    }
    return true;
}

bool gyrocal_load(const void *region, struct gyrocal *cal) {
    const uint8_t *pages = (const uint8_t *)region;
    struct gyrocal found;
    bool any = false;
    identity(cal, GYROCAL_NO_RECORD);
    for (uint8_t i = 0; i < 2; i++) {
        const uint8_t *page = pages + (uint32_t)i * GYROCAL_PAGE_SIZE;
        /* A later sequence number, with wrap-around: (int32_t)(a - b) > 0. */
        if (!erased(page) && decode(page, &found) && (!any || (int32_t)(found.seq - cal->seq) > 0)) {
            found.page = i;
            *cal = found;
            any = true;
        }
    }
    return any;
}

static bool same_setup(const struct gyrocal_setup *a, const struct gyrocal_setup *b) {
    return a->odr_hz == b->odr_hz && a->gyro_range_dps == b->gyro_range_dps && a->accel_range_g == b->accel_range_g &&
           a->sensor == b->sensor;
}

bool gyrocal_load_for(const void *region, const struct gyrocal_setup *runs_at, struct gyrocal *cal) {
    if (!gyrocal_load(region, cal)) {
        return false;
    }
    if (!same_setup(&cal->setup, runs_at)) {
        struct gyrocal_setup made_at = cal->setup;
        identity(cal, GYROCAL_OTHER_SETUP);
        cal->setup = made_at;
        return false;
    }
    return true;
}

#if defined(NRF52840_XXAA) || defined(ARDUINO_ARDUINO_NANO33BLE)
#define GYROCAL_FLASH ((const void *)(uintptr_t)GYROCAL_FLASH_ADDRESS)
#endif

bool gyrocal_load_flash(struct gyrocal *cal) {
#ifdef GYROCAL_FLASH
    return gyrocal_load(GYROCAL_FLASH, cal);
#else
    identity(cal, GYROCAL_NO_RECORD);
    return false;
#endif
}

bool gyrocal_load_flash_for(const struct gyrocal_setup *runs_at, struct gyrocal *cal) {
#ifdef GYROCAL_FLASH
    return gyrocal_load_for(GYROCAL_FLASH, runs_at, cal);
#else
    (void)runs_at;
    identity(cal, GYROCAL_NO_RECORD);
    return false;
#endif
}

static void apply(const float m[3][3], const float off[3], const float in[3], float out[3]) {
    float d[3] = {in[0] - off[0], in[1] - off[1], in[2] - off[2]};
    for (int i = 0; i < 3; i++) {
        out[i] = m[i][0] * d[0] + m[i][1] * d[1] + m[i][2] * d[2];
    }
}

void gyrocal_gyro_dps(const struct gyrocal *cal, const float raw_dps[3], float out_dps[3]) {
    apply(cal->gyro_k, cal->gyro_bias_dps, raw_dps, out_dps);
}

void gyrocal_accel_g(const struct gyrocal *cal, const float raw_g[3], float out_g[3]) {
    apply(cal->accel_m, cal->accel_offset_g, raw_g, out_g);
}

void gyrocal_mag_ut(const struct gyrocal *cal, const float raw_ut[3], float out_ut[3]) {
    apply(cal->mag_a, cal->mag_offset_ut, raw_ut, out_ut);
}

void gyrocal_from_arduino_lsm9ds1_mag(float mag_ut[3]) {
    /* counts = reading * 32768 / 400; uT = counts * 0.014 (0.14 mgauss/LSB at +-4 gauss); the
     * magnetometer's raw axes are the board frame's. */
    const float k = 0.014f * 32768.0f / 400.0f;
    for (int i = 0; i < 3; i++) {
        mag_ut[i] *= k;
    }
}

void gyrocal_from_arduino_bmm150(float mag_ut[3]) {
    map_vec(&BMM150, mag_ut);
}

void gyrocal_mag_refresh_begin(struct gyrocal_mag_refresh *f) {
    memset(f, 0, sizeof *f);
}

void gyrocal_mag_refresh_add(struct gyrocal_mag_refresh *f, const struct gyrocal *cal, const float raw_ut[3]) {
    /* u = A m: |u - c|^2 = B^2 with c = A o, i.e. 2 u.c + (B^2 - c.c) = u.u, linear in c and
     * k = B^2 - c.c. */
    double u[3], x[4], y;
    for (int i = 0; i < 3; i++) {
        u[i] = (double)cal->mag_a[i][0] * raw_ut[0] + (double)cal->mag_a[i][1] * raw_ut[1] + (double)cal->mag_a[i][2] * raw_ut[2];
        x[i] = 2.0 * u[i];
    }
    x[3] = 1.0;
    y = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
    for (int i = 0; i < 4; i++) {
        for (int j = 0; j < 4; j++) {
            f->n[i][j] += x[i] * x[j];
        }
        f->r[i] += x[i] * y;
    }
    f->yy += y * y;
    f->count++;
}

/* The square root of `x` (0 for x <= 0) by Newton's iteration: no libm. */
static double root(double x) {
    double g = x > 1.0 ? x : 1.0;
    if (!(x > 0.0)) {
        return 0.0;
    }
    for (int i = 0; i < 200; i++) {
        double next = 0.5 * (g + x / g);
        if (next >= g) {
            break;
        }
        g = next;
    }
    return g;
}

/* Solves the 3x3 `m x = b` by Cramer's rule; false when singular. */
static bool solve3(float m[3][3], const double b[3], double x[3]) {
    double d = m[0][0] * ((double)m[1][1] * m[2][2] - (double)m[1][2] * m[2][1]) -
               m[0][1] * ((double)m[1][0] * m[2][2] - (double)m[1][2] * m[2][0]) +
               m[0][2] * ((double)m[1][0] * m[2][1] - (double)m[1][1] * m[2][0]);
    if (!(d > 1e-9 || d < -1e-9)) {
        return false;
    }
    for (int k = 0; k < 3; k++) {
        double c[3][3];
        for (int i = 0; i < 3; i++) {
            for (int j = 0; j < 3; j++) {
                c[i][j] = j == k ? b[i] : m[i][j];
            }
        }
        x[k] = (c[0][0] * (c[1][1] * c[2][2] - c[1][2] * c[2][1]) - c[0][1] * (c[1][0] * c[2][2] - c[1][2] * c[2][0]) +
                c[0][2] * (c[1][0] * c[2][1] - c[1][1] * c[2][0])) / d;
    }
    return true;
}

bool gyrocal_mag_refresh_end(struct gyrocal_mag_refresh *f, struct gyrocal *cal) {
    double a[4][5], s[4], o[3], c[3];
    if (!cal->mag_known || f->count < GYROCAL_MAG_REFRESH_MIN) {
        return false;
    }
    /* Gaussian elimination with partial pivoting; a pivot below 1e-9 of the largest diagonal
     * element is a fit the readings do not determine (all in one plane). */
    double scale = 0.0;
    for (int i = 0; i < 4; i++) {
        for (int j = 0; j < 4; j++) {
            a[i][j] = f->n[i][j];
        }
        a[i][4] = f->r[i];
        scale = a[i][i] > scale ? a[i][i] : scale;
    }
    for (int col = 0; col < 4; col++) {
        int p = col;
        for (int i = col + 1; i < 4; i++) {
            if ((a[i][col] < 0 ? -a[i][col] : a[i][col]) > (a[p][col] < 0 ? -a[p][col] : a[p][col])) {
                p = i;
            }
        }
        for (int j = 0; j < 5; j++) {
            double t = a[col][j];
            a[col][j] = a[p][j];
            a[p][j] = t;
        }
        if (!((a[col][col] < 0 ? -a[col][col] : a[col][col]) > 1e-9 * scale)) {
            return false;
        }
        for (int i = col + 1; i < 4; i++) {
            double k = a[i][col] / a[col][col];
            for (int j = col; j < 5; j++) {
                a[i][j] -= k * a[col][j];
            }
        }
    }
    for (int i = 3; i >= 0; i--) {
        double v = a[i][4];
        for (int j = i + 1; j < 4; j++) {
            v -= a[i][j] * s[j];
        }
        s[i] = v / a[i][i];
    }
    double b2 = s[3] + s[0] * s[0] + s[1] * s[1] + s[2] * s[2];
    if (!(b2 > 0.0)) {
        return false;
    }
    c[0] = s[0];
    c[1] = s[1];
    c[2] = s[2];
    if (!solve3(cal->mag_a, c, o)) {
        return false;
    }
    /* The residual of the linear fit (u.u units) over 2B: |m| - B to first order. */
    double rss = f->yy - (s[0] * f->r[0] + s[1] * f->r[1] + s[2] * f->r[2] + s[3] * f->r[3]);
    double field = root(b2), moved = 0.0;
    for (int i = 0; i < 3; i++) {
        moved += (o[i] - cal->mag_offset_ut[i]) * (o[i] - cal->mag_offset_ut[i]);
        cal->mag_offset_ut[i] = (float)o[i];
    }
    f->field_ut = (float)field;
    f->residual_ut = (float)(root(rss / f->count) / (2.0 * field));
    f->moved_ut = (float)root(moved);
    return true;
}

const char *gyrocal_status_str(enum gyrocal_status status) {
    switch (status) {
    case GYROCAL_OK: return "calibration loaded";
    case GYROCAL_NO_RECORD: return "no valid record (never calibrated, or the pages at 0xF8000 were overwritten)";
    case GYROCAL_OTHER_SETUP: return "the record was made with another sensor, ODR or full scale: recalibrate at this one";
    }
    return "unknown status";
}

void gyrocal_from_arduino_lsm9ds1(float gyro_dps[3], float accel_g[3]) {
    /* counts = reading * 32768 / range; datasheet units = counts * sensitivity. */
    const float gyro = 0.070f * 32768.0f / 2000.0f;
    const float accel = 0.000122f * 32768.0f / 4.0f;
    for (int i = 0; i < 3; i++) {
        if (gyro_dps) {
            gyro_dps[i] *= gyro;
        }
        if (accel_g) {
            accel_g[i] *= accel;
        }
    }
    /* The raw axes form a left-handed triad: (-x, y, z) is the board frame. */
    if (gyro_dps) {
        map_vec(&LSM9DS1_AG, gyro_dps);
    }
    if (accel_g) {
        map_vec(&LSM9DS1_AG, accel_g);
    }
}

/* Bosch's API's readings (GYR_CAS applied, Bosch's axes) in the board frame: the CAS undone
 * (x + cas z / 512), then (y, -x, z). */
static void from_bosch(const struct gyrocal *cal, float gyro_dps[3], float accel_g[3]) {
    if (gyro_dps) {
        gyro_dps[0] += (float)cal->gyr_cas * gyro_dps[2] / 512.0f;
        map_vec(&BMI270, gyro_dps);
    }
    if (accel_g) {
        map_vec(&BMI270, accel_g);
    }
}

void gyrocal_from_arduino_bmi270_v10(const struct gyrocal *cal, float gyro_dps[3], float accel_g[3]) {
    from_bosch(cal, gyro_dps, accel_g);
}

void gyrocal_from_arduino_bmi270(const struct gyrocal *cal, float gyro_dps[3], float accel_g[3]) {
    float *v[2] = {gyro_dps, accel_g};
    for (int k = 0; k < 2; k++) {
        if (v[k]) {
            /* Its x = -y, y = -x is its own inverse. */
            float x = -v[k][1];
            v[k][1] = -v[k][0];
            v[k][0] = x;
        }
    }
    from_bosch(cal, gyro_dps, accel_g);
}
