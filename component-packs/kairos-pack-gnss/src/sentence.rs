//! NMEA 0183 sentences to readings: a pure decoder that checks the checksum and parses the fields of
//! GGA and GNS (position, altitude, fix quality, satellites, HDOP, UTC time of day), RMC (date, time,
//! validity, course and speed), VTG (course and speed) and ZDA (date and time), from any talker. Any other
//! sentence with a valid checksum is accepted and passed on as text only. A GGA or GNS without a position
//! is still a fix, with status "no fix" (and its satellites and HDOP): a lost fix is said, not silent.
//!
//! Decision: written here rather than taken from the `nmea` crate, whose exact `serde_with` pin cannot be
//! built together with Zenoh; three sentences' fields are little code, and the tests and fuzz target hold
//! it to the standard's layout (NMEA 0183 v4.11, fields as the receivers' manuals list them).

use chrono::{NaiveDate, NaiveTime, Timelike as _};
use kairos_sdk::FixStatus;

/// Knots to metres per second (1 kn = 1852 m / 3600 s).
const METRES_PER_SECOND_PER_KNOT: f64 = 1852.0 / 3600.0;

/// The longest line read as a sentence: NMEA 0183 allows 82 characters; receivers' proprietary
/// sentences run longer, so some margin.
pub const MAX_SENTENCE_LEN: usize = 256;

/// A position fix (GGA, GNS).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fix {
    /// Degrees north, WGS84 (NaN without a position).
    pub latitude_deg: f64,
    /// Degrees east, WGS84 (NaN without a position).
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
    /// Whether the receiver vouches for that time: a GGA or GNS with a fix, an RMC marked valid (`A`), a
    /// ZDA while the last position sentence had a fix. Only such a time is a reference for a clock.
    pub time_valid: bool,
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
    /// Whether the last GGA, GNS or RMC had a fix.
    fixed: bool,
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
        let fields = checked_fields(line)?;
        let kind = fields[0].get(2..).unwrap_or_default();
        // Proprietary sentences (`$P…`) have no talker: text only, like any sentence not decoded here.
        if fields[0].starts_with('P') {
            return Ok(Reading::default());
        }
        match kind {
            "GGA" => {
                let field = |index: usize| field(&fields, index, "GGA");
                let mut reading = self.timed(time_of(field(1)?)?, None);
                let status = status_of(number::<u8>(field(6)?, "fix quality")?);
                reading.fix = Some(Fix {
                    satellites: number(field(7)?, "satellites")?,
                    hdop: number(field(8)?, "HDOP")?,
                    ..position(&fields, 2, 9, 11, status)?
                });
                Ok(self.vouched(reading))
            }
            "GNS" => {
                let field = |index: usize| field(&fields, index, "GNS");
                let mut reading = self.timed(time_of(field(1)?)?, None);
                let status = status_of_modes(field(6)?);
                reading.fix = Some(Fix {
                    satellites: number(field(7)?, "satellites")?,
                    hdop: number(field(8)?, "HDOP")?,
                    ..position(&fields, 2, 9, 10, status)?
                });
                Ok(self.vouched(reading))
            }
            "RMC" => {
                let field = |index: usize| field(&fields, index, "RMC");
                let mut reading = self.timed(time_of(field(1)?)?, date_of(field(9)?)?);
                reading.motion = Some(Motion {
                    speed_mps: number(field(7)?, "speed")?.map(knots_to_mps),
                    course_deg: number(field(8)?, "course")?,
                });
                self.fixed = field(2)? == "A";
                reading.time_valid = self.fixed && reading.utc_s.is_some();
                Ok(reading)
            }
            "ZDA" => {
                let field = |index: usize| field(&fields, index, "ZDA");
                let date = match (field(2)?, field(3)?, field(4)?) {
                    ("", "", "") => None,
                    (day, month, year) => {
                        let parsed = |text: &str| text.parse::<u32>().ok();
                        let date = parsed(day)
                            .zip(parsed(month))
                            .zip(year.parse::<i32>().ok())
                            .and_then(|((d, m), y)| NaiveDate::from_ymd_opt(y, m, d));
                        Some(date.ok_or_else(|| {
                            SentenceError::Malformed(format!("ZDA date {day:?}, {month:?}, {year:?}"))
                        })?)
                    }
                };
                let mut reading = self.timed(time_of(field(1)?)?, date);
                reading.time_valid = self.fixed && reading.utc_s.is_some();
                Ok(reading)
            }
            "VTG" => {
                let field = |index: usize| field(&fields, index, "VTG");
                Ok(Reading {
                    motion: Some(Motion {
                        speed_mps: number(field(5)?, "speed")?.map(knots_to_mps),
                        course_deg: number(field(1)?, "course")?,
                    }),
                    ..Reading::default()
                })
            }
            // A valid sentence this decoder does not read (GSV, GSA, ...): text only.
            _ => Ok(Reading::default()),
        }
    }

    /// A position sentence's reading, its time vouched for when it has a fix.
    fn vouched(&mut self, mut reading: Reading) -> Reading {
        self.fixed = reading.fix.is_some_and(|fix| fix.status != FixStatus::NoFix);
        reading.time_valid = self.fixed && reading.utc_s.is_some();
        reading
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

fn knots_to_mps(knots: f64) -> f64 {
    knots * METRES_PER_SECOND_PER_KNOT
}

/// The fields of `line` (`$BODY*CS`), after checking its checksum; the first is the address (talker and
/// sentence type, e.g. `GPGGA`).
fn checked_fields(line: &str) -> Result<Vec<&str>, SentenceError> {
    let malformed = |why: &str| SentenceError::Malformed(why.to_owned());
    let Some(rest) = line.strip_prefix('$').or_else(|| line.strip_prefix('!')) else {
        return Err(malformed("does not start with '$'"));
    };
    let Some((body, checksum)) = rest.rsplit_once('*') else {
        return Err(malformed("no '*' before a checksum"));
    };
    if !body.is_ascii() || body.bytes().any(|b| b.is_ascii_control() || b == b'$') {
        return Err(malformed("characters that are not printable ASCII"));
    }
    let Ok(expected) = u8::from_str_radix(checksum, 16)
        .map_err(drop)
        .and_then(|value| if checksum.len() == 2 { Ok(value) } else { Err(()) })
    else {
        return Err(malformed("the checksum is not two hexadecimal digits"));
    };
    if body.bytes().fold(0_u8, |sum, byte| sum ^ byte) != expected {
        return Err(SentenceError::BadChecksum);
    }
    let fields: Vec<&str> = body.split(',').collect();
    if fields[0].len() < 3 || !fields[0].bytes().all(|b| b.is_ascii_alphanumeric()) {
        return Err(malformed("no sentence address (like GPGGA) after '$'"));
    }
    Ok(fields)
}

/// Field `index` of a `sentence`, which must have it (empty when the receiver left it blank).
fn field<'l>(fields: &[&'l str], index: usize, sentence: &str) -> Result<&'l str, SentenceError> {
    fields.get(index).copied().ok_or_else(|| {
        SentenceError::Malformed(format!(
            "{sentence} with {} fields, fewer than {}",
            fields.len() - 1,
            index
        ))
    })
}

/// A number field: `None` when blank.
fn number<T: std::str::FromStr>(text: &str, what: &str) -> Result<Option<T>, SentenceError> {
    if text.is_empty() {
        return Ok(None);
    }
    text.parse()
        .map(Some)
        .map_err(|_| SentenceError::Malformed(format!("{what} {text:?} is not a number")))
}

/// The numbers of `text`'s first three pairs of digits (`hh mm ss`, `dd mm yy`).
fn digit_pairs(text: &str) -> Option<[u32; 3]> {
    let pair = |start: usize| text.get(start..start + 2)?.parse().ok();
    Some([pair(0)?, pair(2)?, pair(4)?])
}

/// `hhmmss.sss`.
fn time_of(text: &str) -> Result<Option<NaiveTime>, SentenceError> {
    if text.is_empty() {
        return Ok(None);
    }
    let bad = || SentenceError::Malformed(format!("time {text:?} is not hhmmss.sss"));
    let [hours, minutes, seconds] = digit_pairs(text).ok_or_else(bad)?;
    let nanos = match text.get(6..) {
        Some("") | None => 0,
        Some(fraction) => {
            let fraction: f64 = fraction.parse().map_err(|_| bad())?;
            if !(0.0..1.0).contains(&fraction) {
                return Err(bad());
            }
            (fraction * 1e9).round().min(999_999_999.0) as u32
        }
    };
    NaiveTime::from_hms_nano_opt(hours, minutes, seconds, nanos)
        .ok_or_else(bad)
        .map(Some)
}

/// `ddmmyy`; years before 80 are this century's.
fn date_of(text: &str) -> Result<Option<NaiveDate>, SentenceError> {
    if text.is_empty() {
        return Ok(None);
    }
    let bad = || SentenceError::Malformed(format!("date {text:?} is not ddmmyy"));
    if text.len() != 6 {
        return Err(bad());
    }
    let [day, month, year] = digit_pairs(text).ok_or_else(bad)?;
    let year = if year < 80 { 2000 + year } else { 1900 + year };
    NaiveDate::from_ymd_opt(i32::try_from(year).map_err(|_| bad())?, month, day)
        .ok_or_else(bad)
        .map(Some)
}

/// `dddmm.mmmm` and its hemisphere as signed degrees; `None` when blank.
fn angle(text: &str, hemisphere: &str, positive: char, negative: char) -> Result<Option<f64>, SentenceError> {
    if text.is_empty() {
        return Ok(None);
    }
    let bad = || {
        SentenceError::Malformed(format!(
            "angle {text:?}{hemisphere} is not dddmm.mmmm and {positive} or {negative}"
        ))
    };
    let value: f64 = text.parse().map_err(|_| bad())?;
    if !value.is_finite() || value < 0.0 {
        return Err(bad());
    }
    let degrees = (value / 100.0).trunc();
    let minutes = value - degrees * 100.0;
    if minutes >= 60.0 {
        return Err(bad());
    }
    let sign = match hemisphere.chars().next() {
        Some(c) if c == positive => 1.0,
        Some(c) if c == negative => -1.0,
        _ => return Err(bad()),
    };
    Ok(Some(sign * (degrees + minutes / 60.0)))
}

/// The position of a GGA or GNS: latitude and its hemisphere at `latitude`, longitude after them, the
/// altitude and geoid separation at their indexes; NaN where the receiver has none.
fn position(
    fields: &[&str],
    latitude: usize,
    altitude: usize,
    separation: usize,
    status: FixStatus,
) -> Result<Fix, SentenceError> {
    let at = |index: usize| fields.get(index).copied().unwrap_or_default();
    Ok(Fix {
        latitude_deg: angle(at(latitude), at(latitude + 1), 'N', 'S')?.unwrap_or(f64::NAN),
        longitude_deg: angle(at(latitude + 2), at(latitude + 3), 'E', 'W')?.unwrap_or(f64::NAN),
        altitude_msl_m: number(at(altitude), "altitude")?,
        geoid_separation_m: number(at(separation), "geoid separation")?,
        status,
        satellites: None,
        hdop: None,
    })
}

/// GNS's mode indicator (one letter per constellation) as a fix status: the best of them (`R` RTK
/// fixed; `D`, `F` or `P` differential, float or precise; `A` autonomous; `N`, `E`, `M`, `S` none).
fn status_of_modes(modes: &str) -> FixStatus {
    let rank = |mode: char| match mode {
        'R' => 3,
        'D' | 'F' | 'P' => 2,
        'A' => 1,
        _ => 0,
    };
    match modes.chars().map(rank).max().unwrap_or(0) {
        3 => FixStatus::RtkFixed,
        2 => FixStatus::Differential,
        1 => FixStatus::Fix,
        _ => FixStatus::NoFix,
    }
}

/// GGA's quality field as a fix status (1 GPS, 2 DGPS, 3 PPS, 4 RTK fixed, 5 RTK float; 0 none, 6
/// estimated, 7 manual, 8 simulated); a fix that is not a measured position is no fix.
fn status_of(quality: Option<u8>) -> FixStatus {
    match quality {
        Some(1 | 3) => FixStatus::Fix,
        Some(2 | 5) => FixStatus::Differential,
        Some(4) => FixStatus::RtkFixed,
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
    fn a_lost_fix_is_said_with_its_satellites_and_hdop_and_its_time_is_no_reference() {
        let mut decoder = Decoder::new();
        let rmc = with_checksum("GPRMC,120000.00,A,4843.1098,N,00213.9980,E,0.0,0.0,251126,,,A");
        assert!(
            decoder.decode(&rmc).unwrap().time_valid,
            "a valid RMC vouches for its time"
        );
        let lost = decoder
            .decode(&with_checksum("GPGGA,120001.00,,,,,0,3,9.9,,,,,,"))
            .unwrap();
        let fix = lost.fix.expect("a GGA without a position is still a fix");
        assert_eq!(fix.status, FixStatus::NoFix);
        assert!(fix.latitude_deg.is_nan() && fix.longitude_deg.is_nan());
        assert_eq!((fix.satellites, fix.hdop), (Some(3), Some(9.9)));
        assert!(lost.utc_s.is_some() && !lost.time_valid);
        let void = with_checksum("GPRMC,120002.00,V,,,,,,,251126,,,N");
        assert!(!decoder.decode(&void).unwrap().time_valid, "a void RMC does not");
        // Nor does a ZDA while there is no fix; with one, it does, and it dates the sentences after it.
        let zda = with_checksum("GPZDA,120003.00,26,11,2026,00,00");
        assert!(!decoder.decode(&zda).unwrap().time_valid);
        let gns = with_checksum("GNGNS,120004.00,4843.1098,N,00213.9980,E,RNA,14,0.7,95.0,47.3,,,V");
        let reading = decoder.decode(&gns).unwrap();
        let fix = reading.fix.unwrap();
        assert_eq!((fix.status, fix.satellites), (FixStatus::RtkFixed, Some(14)));
        assert!((fix.altitude_ellipsoid_m().unwrap() - (95.0 + 47.3)).abs() < 1e-9);
        // 2026-11-26, the ZDA's date (the RMC said the 25th).
        assert_eq!(reading.utc_s, Some(1_795_694_404.0));
        assert!(reading.time_valid);
        assert!(decoder.decode(&zda).unwrap().time_valid);
    }

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

    proptest::proptest! {
        #[test]
        fn any_line_decodes_or_is_refused_without_a_panic(line in "\\PC{0,120}") {
            let _ = Decoder::new().decode(&line);
            let _ = Decoder::new().decode(&with_checksum(&line));
        }

        #[test]
        fn a_gga_written_with_any_position_reads_back(
            latitude in -89.99_f64..89.99,
            longitude in -179.99_f64..179.99,
            quality in 0_u8..9,
        ) {
            let angle = |value: f64, width: usize| {
                let degrees = value.abs().trunc();
                format!("{degrees:0width$}{:07.4}", (value.abs() - degrees) * 60.0)
            };
            let line = with_checksum(&format!(
                "GNGGA,120000.00,{},{},{},{},{quality},9,0.8,100.0,M,47.0,M,,",
                angle(latitude, 2),
                if latitude < 0.0 { 'S' } else { 'N' },
                angle(longitude, 3),
                if longitude < 0.0 { 'W' } else { 'E' },
            ));
            let fix = Decoder::new().decode(&line).unwrap().fix.unwrap();
            proptest::prop_assert!((fix.latitude_deg - latitude).abs() < 1e-5);
            proptest::prop_assert!((fix.longitude_deg - longitude).abs() < 1e-5);
        }
    }
}
