//! NMEA 0183 sentences to readings: a pure decoder over the `nmea` crate, which checks the checksum and
//! parses the fields. What is decoded: GGA (position, altitude, fix quality, satellites, HDOP, UTC time of
//! day), RMC (date, time, course and speed), VTG (course and speed). Any other sentence with a valid
//! checksum is accepted and passed on as text only.

use chrono::{NaiveDate, NaiveTime, Timelike as _};
use kairos_sdk::FixStatus;
use nmea::sentences::FixType;
use nmea::{Error as NmeaError, ParseResult};

/// Knots to metres per second (1 kn = 1852 m / 3600 s).
const METRES_PER_SECOND_PER_KNOT: f64 = 1852.0 / 3600.0;

/// The longest line read as a sentence: NMEA 0183 allows 82 characters; receivers' proprietary
/// sentences run longer, so some margin.
pub const MAX_SENTENCE_LEN: usize = 256;

/// A position fix (GGA).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fix {
    /// Degrees north, WGS84.
    pub latitude_deg: f64,
    /// Degrees east, WGS84.
    pub longitude_deg: f64,
    /// Altitude above mean sea level, metres.
    pub altitude_msl_m: Option<f64>,
    /// Geoid separation (ellipsoid − mean sea level), metres.
    pub geoid_separation_m: Option<f64>,
    /// The fix quality.
    pub status: FixStatus,
    /// Satellites used.
    pub satellites: Option<u32>,
    /// Horizontal dilution of precision.
    pub hdop: Option<f64>,
}

impl Fix {
    /// Altitude above the WGS84 ellipsoid: mean sea level plus the geoid separation (0 when not sent).
    pub fn altitude_ellipsoid_m(&self) -> Option<f64> {
        Some(self.altitude_msl_m? + self.geoid_separation_m.unwrap_or(0.0))
    }
}

/// Course and speed over ground (RMC, VTG).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Motion {
    /// Speed over ground, m/s.
    pub speed_mps: Option<f64>,
    /// Course over ground, degrees from true north.
    pub course_deg: Option<f64>,
}

/// What one sentence said.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Reading {
    /// A position fix (GGA with a position).
    pub fix: Option<Fix>,
    /// Course and speed.
    pub motion: Option<Motion>,
    /// The receiver's UTC time, seconds since the UNIX epoch, when the sentence has a time and the date
    /// is known (RMC carries it; GGA takes the last date seen, moving to the next day at midnight).
    pub utc_s: Option<f64>,
    /// The receiver's UTC time of day, seconds since midnight, when the sentence has a time.
    pub time_of_day_s: Option<f64>,
}

/// Why a line is not a sentence.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SentenceError {
    /// The checksum does not match the sentence.
    #[error("bad checksum")]
    BadChecksum,
    /// Not an NMEA sentence, or fields that do not parse.
    #[error("malformed: {0}")]
    Malformed(String),
}

/// Decodes sentences, remembering the date from RMC for the sentences that carry a time alone.
#[derive(Debug, Default, Clone)]
pub struct Decoder {
    date: Option<NaiveDate>,
    last_time: Option<NaiveTime>,
}

impl Decoder {
    /// A decoder that knows no date yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Decodes one line (with or without its line ending).
    ///
    /// # Errors
    ///
    /// A bad checksum, a line that is not a sentence, or a decoded sentence whose fields do not parse.
    pub fn decode(&mut self, line: &str) -> Result<Reading, SentenceError> {
        let line = line.trim_end_matches(['\r', '\n']);
        if line.len() > MAX_SENTENCE_LEN {
            return Err(SentenceError::Malformed(format!(
                "{} characters, more than {MAX_SENTENCE_LEN}",
                line.len()
            )));
        }
        match nmea::parse_str(line) {
            Ok(ParseResult::GGA(gga)) => {
                let mut reading = self.timed(gga.fix_time, None);
                if let (Some(latitude_deg), Some(longitude_deg)) = (gga.latitude, gga.longitude) {
                    reading.fix = Some(Fix {
                        latitude_deg,
                        longitude_deg,
                        altitude_msl_m: gga.altitude.map(f64::from),
                        geoid_separation_m: gga.geoid_separation.map(f64::from),
                        status: status_of(gga.fix_type),
                        satellites: gga.fix_satellites,
                        hdop: gga.hdop.map(f64::from),
                    });
                }
                Ok(reading)
            }
            Ok(ParseResult::RMC(rmc)) => {
                let mut reading = self.timed(rmc.fix_time, rmc.fix_date);
                reading.motion = Some(Motion {
                    speed_mps: rmc.speed_over_ground.map(knots_to_mps),
                    course_deg: rmc.true_course.map(f64::from),
                });
                Ok(reading)
            }
            Ok(ParseResult::VTG(vtg)) => Ok(Reading {
                motion: Some(Motion {
                    speed_mps: vtg.speed_over_ground.map(knots_to_mps),
                    course_deg: vtg.true_course.map(f64::from),
                }),
                ..Reading::default()
            }),
            // A valid sentence this decoder does not read (GSV, GSA, proprietary ones): text only.
            Ok(_) | Err(NmeaError::Unsupported(_) | NmeaError::DisabledSentence) => Ok(Reading::default()),
            Err(NmeaError::ChecksumMismatch { .. }) => Err(SentenceError::BadChecksum),
            Err(other) => Err(SentenceError::Malformed(other.to_string())),
        }
    }

    /// A reading carrying the sentence's time, with the date `date` or the one last seen.
    fn timed(&mut self, time: Option<NaiveTime>, date: Option<NaiveDate>) -> Reading {
        let Some(time) = time else {
            return Reading::default();
        };
        if let Some(date) = date {
            self.date = Some(date);
        } else if let (Some(date), Some(last)) = (self.date, self.last_time)
            && time < last
            && last.num_seconds_from_midnight() > 23 * 3600
            && time.num_seconds_from_midnight() < 3600
        {
            // Midnight passed between two sentences without a date.
            self.date = date.succ_opt();
        }
        self.last_time = Some(time);
        let time_of_day_s = f64::from(time.num_seconds_from_midnight()) + f64::from(time.nanosecond()) * 1e-9;
        let utc_s = self.date.map(|date| {
            let midnight = date.and_time(NaiveTime::MIN).and_utc().timestamp();
            midnight as f64 + time_of_day_s
        });
        Reading {
            utc_s,
            time_of_day_s: Some(time_of_day_s),
            ..Reading::default()
        }
    }
}

fn knots_to_mps(knots: f32) -> f64 {
    f64::from(knots) * METRES_PER_SECOND_PER_KNOT
}

/// GGA's quality field as a fix status; a fix that is not a measured position is no fix.
fn status_of(fix_type: Option<FixType>) -> FixStatus {
    match fix_type {
        Some(FixType::Gps | FixType::Pps) => FixStatus::Fix,
        Some(FixType::DGps | FixType::FloatRtk) => FixStatus::Differential,
        Some(FixType::Rtk) => FixStatus::RtkFixed,
        _ => FixStatus::NoFix,
    }
}

/// `body` (what lies between `$` and `*`) as a whole sentence with its checksum: for tests and for
/// programs that write NMEA.
pub fn with_checksum(body: &str) -> String {
    let checksum = body.bytes().fold(0_u8, |sum, byte| sum ^ byte);
    format!("${body}*{checksum:02X}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gga_gives_position_altitude_quality_satellites_hdop_and_time() {
        let mut decoder = Decoder::new();
        let line = with_checksum("GPGGA,092750.000,5321.6802,N,00630.3372,W,1,8,1.03,61.7,M,55.2,M,,");
        let reading = decoder.decode(&line).unwrap();
        let fix = reading.fix.unwrap();
        assert!((fix.latitude_deg - (53.0 + 21.6802 / 60.0)).abs() < 1e-9);
        assert!((fix.longitude_deg + (6.0 + 30.3372 / 60.0)).abs() < 1e-9);
        assert!((fix.altitude_ellipsoid_m().unwrap() - (61.7 + 55.2)).abs() < 1e-3);
        assert_eq!(fix.status, FixStatus::Fix);
        assert_eq!(fix.satellites, Some(8));
        assert!((fix.hdop.unwrap() - 1.03).abs() < 1e-6);
        assert_eq!(reading.time_of_day_s, Some(9.0 * 3600.0 + 27.0 * 60.0 + 50.0));
        // No date seen yet: no full UTC time.
        assert_eq!(reading.utc_s, None);
    }

    #[test]
    fn rmc_gives_the_date_speed_in_metres_per_second_and_course_and_dates_later_ggas() {
        let mut decoder = Decoder::new();
        let rmc = with_checksum("GPRMC,225446.00,A,4916.45,N,12311.12,W,000.5,054.7,191194,020.3,E");
        let reading = decoder.decode(&rmc).unwrap();
        let motion = reading.motion.unwrap();
        assert!((motion.speed_mps.unwrap() - 0.5 * 1852.0 / 3600.0).abs() < 1e-6);
        assert!((motion.course_deg.unwrap() - 54.7).abs() < 1e-4);
        // 1994-11-19 22:54:46 UTC.
        assert_eq!(reading.utc_s, Some(785_285_686.0));
        let gga = with_checksum("GPGGA,225447.00,4916.45,N,12311.12,W,2,10,0.9,10.0,M,-17.0,M,,");
        let later = decoder.decode(&gga).unwrap();
        assert_eq!(later.utc_s, Some(785_285_687.0));
        assert_eq!(later.fix.unwrap().status, FixStatus::Differential);
    }

    #[test]
    fn midnight_moves_the_date_of_sentences_without_one() {
        let mut decoder = Decoder::new();
        decoder
            .decode(&with_checksum(
                "GPRMC,235959.00,A,4916.45,N,12311.12,W,0.0,0.0,191194,,",
            ))
            .unwrap();
        let after = decoder
            .decode(&with_checksum(
                "GPGGA,000001.00,4916.45,N,12311.12,W,1,5,1.0,1.0,M,0.0,M,,",
            ))
            .unwrap();
        assert_eq!(after.utc_s, Some(785_289_601.0));
    }

    #[test]
    fn bad_checksums_and_noise_are_refused_and_other_sentences_accepted() {
        let mut decoder = Decoder::new();
        let good = with_checksum("GPGGA,092750.000,5321.6802,N,00630.3372,W,1,8,1.03,61.7,M,55.2,M,,");
        let bad = format!("{}00", &good[..good.len() - 2]);
        assert_eq!(decoder.decode(&bad), Err(SentenceError::BadChecksum));
        assert!(matches!(
            decoder.decode("\u{1}\u{2}garbage"),
            Err(SentenceError::Malformed(_))
        ));
        assert!(matches!(
            decoder.decode(&good[..30]),
            Err(SentenceError::Malformed(_))
        ));
        assert!(matches!(
            decoder.decode(&"$".repeat(300)),
            Err(SentenceError::Malformed(_))
        ));
        let gsv = with_checksum("GPGSV,3,1,11,03,03,111,00,04,15,270,00,06,01,010,00,13,06,292,00");
        assert_eq!(decoder.decode(&gsv), Ok(Reading::default()));
    }
}
