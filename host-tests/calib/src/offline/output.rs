//! The tool's JSON output and the record of a result.

use super::*;
use calib_core::formats::export::{AccelJson, GyroJson, MagJson};

/// The tool's JSON output: the calibration to apply (`gyro` and `accel` in the one schema of
/// `calib_core::formats::export`), then everything about its quality.
#[derive(Debug, Clone, Serialize)]
pub struct Output<'a> {
    /// `ω = K (g − b)`; `null` when the log does not support it (see `quality.missing`).
    pub gyro: Option<GyroJson>,
    /// `f = M (a − o)`.
    pub accel: AccelJson,
    /// `m = A (m_raw − o)` (µT, the calibrated accelerometer's frame); `null` without
    /// magnetometer columns or when the hand-held rows do not support it (`quality.missing`).
    pub mag: Option<MagJson>,
    /// Quality of every part.
    pub quality: QualityOut<'a>,
}

/// The magnetometer's quality, or why it failed, and which readings were used.
#[derive(Debug, Clone, Serialize)]
pub struct MagQualityOut<'a> {
    /// The fit's figures (`null` on failure).
    pub fit: Option<&'a calib_core::estimators::mag::MagCal>,
    /// Why there is no calibration (`null` on success).
    pub error: Option<String>,
    /// Readings of hand-held rows offered to the fit.
    pub hand_held_readings: usize,
    /// Readings of rig rows (a servo commanded, its motor's magnet near), left out of the fit.
    pub rig_readings_left_out: usize,
    /// The magnetometer's axes turned against the accelerometer's, as the poses' dips show
    /// (`null`: as logged); `A` and the offset apply to the readings as logged.
    pub axes: Option<&'a super::MagAxes>,
}

/// The accelerometer's fit and its 1σ.
#[derive(Debug, Clone, Serialize)]
pub struct AccelQuality<'a> {
    /// The fit's figures.
    #[serde(flatten)]
    pub fit: &'a AccelCal,
    /// The 1σ of its offsets and diagonal gains (`null`: no fit, or a replayed run of the
    /// firmware).
    pub sigma: Option<&'a AccelSigma>,
}

/// One estimator's outcome: its result, or why it failed.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum EstimatorOut<'a> {
    /// The result.
    Ok(&'a GyroCal),
    /// The failure.
    Failed {
        /// What went wrong.
        error: String,
    },
}

impl<'a> EstimatorOut<'a> {
    fn of(r: &'a Result<GyroCal, Error>) -> Self {
        match r {
            Ok(c) => EstimatorOut::Ok(c),
            Err(e) => EstimatorOut::Failed { error: e.to_string() },
        }
    }
}

/// The full `K`'s outcome.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum FullOut<'a> {
    /// The result.
    Ok(&'a FullCal),
    /// The failure.
    Failed {
        /// What went wrong.
        error: String,
    },
}

/// Both estimators.
#[derive(Debug, Clone, Serialize)]
pub struct Estimators<'a> {
    /// The speed-free sweep estimator.
    pub sweep: EstimatorOut<'a>,
    /// The paper's estimator.
    pub paper: EstimatorOut<'a>,
}

/// What the phase detection found.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Segments {
    /// Still segments.
    pub still: usize,
    /// Accelerometer poses (hand-held or tilt servo).
    pub handheld_poses: usize,
    /// Rig poses.
    pub rig_poses: usize,
    /// Moves between rig poses.
    pub moves: usize,
}

/// The moves between consecutive hand-held poses (the rotation constraints): how many were used,
/// and why the others were not.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HandMoves {
    /// Moves between consecutive hand-held poses.
    pub total: usize,
    /// Used.
    pub kept: usize,
    /// Of those, turns about the vertical: they constrain their axis only, or with
    /// `--whole-turns` their angle too (`vertical_turns` says which).
    pub vertical: usize,
    /// `axis only` or `whole turns`.
    pub vertical_turns: &'static str,
    /// Dropped, by reason (`saturated`, `too_fast`, `too_short`, `bias_drifted`, `no_room`,
    /// `unseen`, `gap`): every reason with its count.
    pub dropped: std::collections::BTreeMap<&'static str, u16>,
}

impl HandMoves {
    /// `"6 of 9 moves between poses used, dropped: 3 saturated"`, or `None` when none was dropped.
    pub fn dropped_summary(&self) -> Option<String> {
        let dropped: Vec<String> = self.dropped.iter().filter(|(_, n)| **n > 0).map(|(r, n)| format!("{n} {r}")).collect();
        (!dropped.is_empty()).then(|| format!("{} of {} moves between poses used, dropped: {}", self.kept, self.total, dropped.join(", ")))
    }

    /// When turns about the vertical constrained their axes only: how many, and that
    /// `--whole-turns` would use their angle (a Ferraris session's 360° turns on a table).
    pub fn vertical_hint(&self) -> Option<String> {
        (self.vertical > 0 && self.vertical_turns == "axis only").then(|| {
            format!(
                "{} of the moves used turn about the vertical and constrain their axis only: if they were whole turns (360 deg), --whole-turns uses their angle too",
                self.vertical
            )
        })
    }

    /// The summary of `rotations`, recorded under `limits`.
    pub fn of<const M: usize, const C: usize, const P: usize>(rotations: &Rotations<M, C, P>, limits: &RotationLimits) -> Self {
        let dropped: std::collections::BTreeMap<_, _> =
            calib_core::estimators::rotation::Rejected::ALL.iter().zip(rotations.rejected()).map(|(r, n)| (r.name(), n)).collect();
        let kept = rotations.moves().len();
        HandMoves {
            total: kept + dropped.values().map(|&n| n as usize).sum::<usize>(),
            kept,
            vertical: rotations.moves().iter().filter(|m| m.vertical).count(),
            vertical_turns: if limits.whole_turns { "whole turns" } else { "axis only" },
            dropped,
        }
    }
}

/// Quality of every part of the calibration.
#[derive(Debug, Clone, Serialize)]
pub struct QualityOut<'a> {
    /// The parts of the calibration the log did not support, each with the reason.
    pub missing: Vec<String>,
    /// The one-axis gyro estimator's quality report; its `sigma_k` is the 1σ of the diagonal
    /// of the `K` that is reported (the full `K`'s when it is the full one).
    pub gyro: Option<GyroQuality>,
    /// The bias.
    pub bias: &'a Bias,
    /// The accelerometer fit.
    pub accel: AccelQuality<'a>,
    /// Why the accelerometer has its model: the F-test of the 9-parameter model's cross terms
    /// (`null`: only one model could be fitted).
    pub accel_model_test: Option<AccelModelOut>,
    /// What the tool left out, each with its count, why and what to do (also on stderr).
    pub left_out: &'a [String],
    /// Both estimators' outcomes.
    pub estimators: Estimators<'a>,
    /// On a pan/tilt log, the full `K`'s quality (or its error).
    pub full: Option<FullOut<'a>>,
    /// The moves between hand-held poses (`null` for a replayed run of the firmware: its log
    /// says it).
    pub hand_moves: Option<&'a HandMoves>,
    /// The spin rate the paper estimator used (°/s).
    pub spin_rate_dps: Option<f32>,
    /// Where it came from (`servo column` or `accelerometer`).
    pub spin_rate_source: Option<&'static str>,
    /// The log's sample rate, and whether it is an LSM9DS1 ODR (false: another sensor's log).
    pub sample_rate: TimeBase,
    /// Phases found.
    pub segments: Segments,
    /// The rest thresholds used (raised to the log's noise floor).
    pub rest_thresholds: &'a RestConfig,
    /// Log messages between the rows that were skipped.
    pub log_messages: usize,
    /// The log was a run of the firmware's procedure, replayed through it under this
    /// configuration (`null`: phases found from the data).
    pub replayed: Option<&'static str>,
    /// The magnetometer (`null`: the log has none).
    pub mag: Option<MagQualityOut<'a>>,
    /// How the gyro's axes follow the accelerometer's: `right-handed`, or `mirrored` (calibrated
    /// in the log's own axes: `K` and the bias apply to the readings as logged).
    pub gyro_axes: &'static str,
    /// For `mirrored`, the evidence: how many moves turn gravity by each rule.
    pub gyro_axes_evidence: Option<AxesEvidence>,
}

/// The F-test that chose the accelerometer model, and what it decided.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct AccelModelOut {
    #[serde(flatten)]
    pub test: pipeline::ModelTest,
    /// `nine_param: cross terms significant` or `six_param: cross terms not significant`.
    pub chosen: &'static str,
}

/// The moves that turn gravity by the right- and by the left-hand rule in the log's axes.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct AxesEvidence {
    pub right_hand_moves: u8,
    pub left_hand_moves: u8,
}

const NO_SPIN: Result<GyroCal, Error> = Err(Error::NoSpin { rate_dps: 0.0, min_dps: CONFIG.steady.min_dps });

impl Calibration {
    /// The parts the log did not support, each with the reason (empty: a full calibration).
    pub fn missing(&self) -> Vec<String> {
        let mut m = vec![];
        match (&self.gyro, &self.full) {
            (_, Some(Ok(_))) => {}
            (Err(e @ OfflineError::Calib { stage: driven::HAND_HELD_STAGE, error }), _) => {
                // A result rejected after some moves were dropped: say which, with their count.
                // Turns about the vertical taken as axes only: the option that uses their angle.
                let summary =
                    self.hand_moves.as_ref().and_then(HandMoves::dropped_summary).filter(|_| !matches!(error, Error::MovesDropped { .. }));
                let hint = self.hand_moves.as_ref().and_then(HandMoves::vertical_hint);
                m.push([Some(format!("gyro: {e}")), self.advice(), summary, hint].into_iter().flatten().collect::<Vec<_>>().join("; "));
            }
            (Err(e), Some(Err(f))) => {
                let advice = self.advice().map_or(String::new(), |a| format!(": {a}"));
                m.push(format!("gyro: full K: {f}{advice}; one axis: {e}"))
            }
            (Err(e), None) => m.push(format!("gyro: {e}")),
            (Ok(_), Some(Err(f))) => m.push(format!("full K (the diagonal K of one axis is given): {f}")),
            (Ok(_), None) => {}
        }

        if let Some(Err(e)) = self.mag.as_ref().map(|m| &m.cal) {
            m.push(format!("magnetometer: {e}"));
        }
        if self.accel.model == AccelModel::None {
            m.push(format!(
                "accelerometer: {} accelerometer poses, need {} (one more than the 6 unknowns of the smallest fit: as many poses as unknowns interpolate them and determine nothing); {}; the identity is used",
                self.handheld_poses,
                pipeline::SIX_PARAM_POSES,
                self.pose_directions()
            ));
        }
        m
    }

    /// Which of the six axis directions (±x, ±y, ±z: the sensor axis gravity is nearest to) the
    /// accelerometer poses cover, and which they miss.
    pub fn pose_directions(&self) -> String {
        let mut seen = [false; 6];
        for s in self.phases.segments.iter().filter(|s| !s.is_rig_pose()) {
            let a = s.accel.mean();
            let axis = (0..3).max_by(|&i, &j| a[i].abs().total_cmp(&a[j].abs())).unwrap_or(0);
            seen[2 * axis + usize::from(a[axis] < 0.0)] = true;
        }
        let names = ["+x", "-x", "+y", "-y", "+z", "-z"];
        let list = |want: bool| names.iter().zip(seen).filter(|(_, s)| *s == want).map(|(n, _)| *n).collect::<Vec<_>>().join(" ");
        match list(false) {
            missing if missing.is_empty() => format!("poses up along every axis ({}); add poses between the faces", list(true)),
            missing => format!("no pose with {missing} up (poses with {} up); add them", list(true)),
        }
    }

    /// The tool's output; `log_messages` lines of the log were skipped as messages.
    pub fn output(&self, log_messages: usize) -> Output<'_> {
        let gyro = self.gyro.as_ref().ok();
        let full = self.full.as_ref().and_then(|f| f.as_ref().ok());
        let chosen = match (full, gyro) {
            (Some(f), _) => Some(GyroJson { k: f.k, bias_dps: self.bias.bias_dps, method: Method::Full }),
            (None, g) => g.map(|g| GyroJson { k: g.k, bias_dps: self.bias.bias_dps, method: g.method }),
        };
        let mag_cal = self.mag.as_ref().and_then(|m| m.cal.as_ref().ok());
        Output {
            gyro: chosen,
            accel: AccelJson { m: self.accel.m, offset_g: self.accel.offset_g },
            mag: mag_cal.map(|c| MagJson { a: c.a, offset_ut: c.offset_ut }),
            quality: QualityOut {
                missing: self.missing(),
                gyro: gyro.map(|g| GyroQuality {
                    sigma_k: full.map_or(g.quality.sigma_k, |f| core::array::from_fn(|i| f.sigma_k[i][i])),
                    ..g.quality
                }),
                bias: &self.bias,
                accel: AccelQuality { fit: &self.accel, sigma: self.accel_sigma.as_ref() },
                accel_model_test: self.accel_test.map(|test| AccelModelOut {
                    test,
                    chosen: if test.nine() {
                        "nine_param: its cross terms are significant (f above critical, 5 % level)"
                    } else {
                        "six_param: the cross terms of nine are not significant (f at most critical, 5 % level)"
                    },
                }),
                left_out: &self.left_out,
                estimators: Estimators {
                    sweep: EstimatorOut::of(&self.sweep),
                    paper: EstimatorOut::of(self.paper.as_ref().unwrap_or(&NO_SPIN)),
                },
                spin_rate_dps: self.spin_rate.map(|r| r.0),
                spin_rate_source: self.spin_rate.map(|r| r.1),
                sample_rate: self.time_base,
                segments: Segments {
                    still: self.phases.segments.len(),
                    handheld_poses: self.handheld_poses,
                    rig_poses: self.rig_poses,
                    moves: self.moves,
                },
                full: self.full.as_ref().map(|f| match f {
                    Ok(f) => FullOut::Ok(f),
                    Err(e) => FullOut::Failed { error: e.to_string() },
                }),
                hand_moves: self.hand_moves.as_ref(),
                rest_thresholds: &self.phases.rest,
                log_messages,
                replayed: self.replayed,
                gyro_axes: if self.mirrored.is_some() { "mirrored" } else { "right-handed" },
                gyro_axes_evidence: match self.mirrored {
                    Some(Error::AxesMirrored { right_hand, left_hand }) => {
                        Some(AxesEvidence { right_hand_moves: right_hand, left_hand_moves: left_hand })
                    }
                    _ => None,
                },
                mag: self.mag.as_ref().map(|m| MagQualityOut {
                    fit: m.cal.as_ref().ok(),
                    error: m.cal.as_ref().err().map(|e| e.to_string()),
                    hand_held_readings: m.used,
                    rig_readings_left_out: m.left_out,
                    axes: m.axes.as_ref(),
                }),
            },
        }
    }

    /// The result as a flash record, for `calib_core::formats::export`: the gyro `K` of
    /// [`Self::output`] (the full `K` if there is one) with its quality, the bias and the
    /// accelerometer; `seq` 0 (never stored: the export names the source `calib`), temperature
    /// and tempco unknown (the offline fit takes a log's temperatures only for its shaky poses'
    /// warm-up and reports no coefficient; a replay of the firmware's log does, as the firmware
    /// did), the setup the log states, else its
    /// rate (nominal: [`TimeBase::nominal_hz`]) at the firmware's default full scales. `None`
    /// without a gyro result.
    pub fn record(&self) -> Option<Record> {
        let setup =
            self.setup.unwrap_or(record::SensorSetup { odr_hz: self.time_base.nominal_hz() as f32, ..record::SensorSetup::DEFAULT });
        if let Some(r) = self.replayed_record {
            return Some(Record { seq: 0, setup, ..r });
        }
        let mag = self.mag.as_ref().and_then(|m| m.cal.as_ref().ok().copied());
        let ctx = record::Context { seq: 0, temp_c: None, gyro_bias_dps: self.bias.bias_dps, accel: self.accel, setup, tempco: None, mag };
        // The full K's poses: every rig pose (each one went into its axes).
        let rig_poses = self.phases.segments.iter().filter(|s| s.is_rig_pose()).count().min(u8::MAX as usize) as u8;
        match (&self.full, &self.gyro) {
            (Some(Ok(f)), _) => Some(ctx.full(f, rig_poses)),
            (_, Ok(g)) => Some(ctx.one_axis(g)),
            _ => None,
        }
    }

    /// The output as one line of JSON.
    pub fn json(&self, log_messages: usize) -> String {
        serde_json::to_string(&self.output(log_messages)).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
    }
}
