//! The sensor a benchmark simulates (`--setup`): the part, its ODR and full scales, for the rigs
//! (`rig_sim`'s sensor model) and for the procedure (`SensorSetup`) alike.

use calib_core::formats::record::{Sensor, SensorSetup};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rig_sim::sim::{AccelRange, GyroRange, RigConfig, BMI270_ODR_ERROR, LSM9DS1_ODR_ERROR};

/// The simulated sensor and its settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Setup {
    /// The LSM9DS1 at the firmware's settings: 119 Hz, ±500 °/s, ±2 g.
    Default,
    /// The LSM9DS1 at Arduino_LSM9DS1's: 119 Hz, ±2000 °/s, ±4 g.
    ArduinoLsm9ds1,
    /// The Rev2's BMI270 at the firmware's Rev2 settings: 100 Hz, ±500 °/s, ±2 g.
    Bmi270,
    /// The BMI270 at Arduino_BMI270_BMM150's: 100 Hz, ±2000 °/s, ±4 g.
    ArduinoBmi270,
}

impl Setup {
    /// The procedure's setup.
    pub fn setup(self) -> SensorSetup {
        let bmi = |gyro_range_dps, accel_range_g| SensorSetup {
            odr_hz: 100.0,
            gyro_range_dps,
            accel_range_g,
            sensor: Sensor::Bmi270 { gyr_cas: 0, user_gain: false },
        };
        match self {
            Setup::Default => SensorSetup::DEFAULT,
            Setup::ArduinoLsm9ds1 => SensorSetup::ARDUINO_LSM9DS1,
            Setup::Bmi270 => bmi(500.0, 2.0),
            Setup::ArduinoBmi270 => bmi(2000.0, 4.0),
        }
    }

    /// The range of the part's relative ODR error the rigs draw from.
    pub fn odr_error_range(self) -> (f64, f64) {
        match self {
            Setup::Default | Setup::ArduinoLsm9ds1 => LSM9DS1_ODR_ERROR,
            Setup::Bmi270 | Setup::ArduinoBmi270 => BMI270_ODR_ERROR,
        }
    }

    /// `cfg` with the sensor to match (`seed`: the draw of a BMI270's ODR error,
    /// `RigConfig::on_bmi270`).
    pub fn rig(self, mut cfg: RigConfig, seed: u64) -> RigConfig {
        let rng = &mut ChaCha8Rng::seed_from_u64(seed);
        match self {
            Setup::Default => (cfg.gyro.range, cfg.accel.range) = (GyroRange::Dps500, AccelRange::G2),
            Setup::ArduinoLsm9ds1 => (cfg.gyro.range, cfg.accel.range) = (GyroRange::Dps2000, AccelRange::G4),
            Setup::Bmi270 => cfg = cfg.on_bmi270(500, 2, rng),
            Setup::ArduinoBmi270 => cfg = cfg.on_bmi270(2000, 4, rng),
        }
        cfg
    }

    /// The JSON of the setup a summary states.
    pub fn json(self) -> serde_json::Value {
        let s = self.setup();
        serde_json::json!({"odr_hz": s.odr_hz, "gyro_range_dps": s.gyro_range_dps, "accel_range_g": s.accel_range_g,
            "sensor": s.sensor.name()})
    }
}
