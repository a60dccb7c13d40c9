/*
  GyroCal - Calibrated Gyro

  Reads the calibration the gyrocal firmware stored in this board's flash (it survives the upload
  of this sketch) and prints Arduino_LSM9DS1's gyro and accelerometer readings calibrated with it.

  Calibrate first with the gyrocal firmware at Arduino_LSM9DS1's configuration (119 Hz,
  +-2000 dps, +-4 g: console command `p`, or built with --features arduino-lsm9ds1); a record made
  at another configuration is refused. Board: Arduino Nano 33 BLE (Rev1, LSM9DS1).
*/

#include <Arduino_LSM9DS1.h>
#include <gyrocal.h>

struct gyrocal cal;

void setup() {
  Serial.begin(115200);
  while (!Serial);
  if (!IMU.begin()) {
    Serial.println("Failed to initialize IMU!");
    while (1);
  }
  gyrocal_load_flash_for(&GYROCAL_SETUP_ARDUINO_LSM9DS1, &cal);
  Serial.print("gyrocal: ");
  Serial.println(gyrocal_status_str(cal.status));
  if (cal.status == GYROCAL_OK) {
    Serial.print("record seq ");
    Serial.print(cal.seq);
    Serial.print(", K diagonal ");
    Serial.print(cal.gyro_k[0][0], 5);
    Serial.print(' ');
    Serial.print(cal.gyro_k[1][1], 5);
    Serial.print(' ');
    Serial.println(cal.gyro_k[2][2], 5);
  }
  Serial.println("gx\tgy\tgz (dps)\tax\tay\taz (g)");
}

void loop() {
  float g[3], a[3];
  if (IMU.gyroscopeAvailable() && IMU.accelerationAvailable()) {
    IMU.readGyroscope(g[0], g[1], g[2]);
    IMU.readAcceleration(a[0], a[1], a[2]);
    gyrocal_from_arduino_lsm9ds1(g, a);
    gyrocal_gyro_dps(&cal, g, g);
    gyrocal_accel_g(&cal, a, a);
    for (int i = 0; i < 3; i++) {
      Serial.print(g[i], 3);
      Serial.print('\t');
    }
    for (int i = 0; i < 3; i++) {
      Serial.print(a[i], 4);
      Serial.print(i < 2 ? '\t' : '\n');
    }
  }
}
