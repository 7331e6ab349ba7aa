//! One dataset row: the conditions of a walk and its canonical outcome.

use std::io::{self, Write};

use crate::conditions::Conditions;
use crate::ranges::Short;
use crate::walk::CanonicalWalk;

/// Column names of the CSV header, in row order.
pub const COLUMNS: [&str; 13] = [
    "tau",
    "g",
    "albedo",
    "n",
    "cos_theta",
    "beta",
    "alpha",
    "ev_x",
    "ev_y",
    "ev_z",
    "ev_wx",
    "ev_wy",
    "ev_wz",
];

/// Bytes of one encoded row.
pub const ROW_BYTES: usize = 56;

/// One walk: conditions (τ, g, φ), event count N, exit (cos θ, β, α) and the
/// representative event (X, W), all in the canonical frame.
///
/// Values are stored as f32 (ample for training) except φ, which is f64 because the
/// authors' albedos sit within 10⁻⁶ of 1, where f32 keeps only one significant digit of
/// 1 − φ, and EventGen is conditioned on (1 − φ)^{1/6}.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Row {
    pub tau: f32,
    pub g: f32,
    pub albedo: f64,
    pub n: u32,
    pub cos_theta: f32,
    pub beta: f32,
    pub alpha: f32,
    pub ev_pos: [f32; 3],
    pub ev_dir: [f32; 3],
}

impl Row {
    pub fn new(c: Conditions, w: &CanonicalWalk) -> Self {
        let f = |v: f64| v as f32;
        Self {
            tau: f(c.tau),
            g: f(c.g),
            albedo: c.albedo,
            n: u32::try_from(w.n).unwrap_or(u32::MAX),
            cos_theta: f(w.exit.cos_theta),
            beta: f(w.exit.beta),
            alpha: f(w.exit.alpha),
            ev_pos: w.event_pos.as_vec3().to_array(),
            ev_dir: w.event_dir.as_vec3().to_array(),
        }
    }

    /// Little-endian encoding in column order.
    pub fn encode(&self, out: &mut [u8; ROW_BYTES]) {
        let mut at = 0;
        let mut put = |bytes: &[u8]| {
            out[at..at + bytes.len()].copy_from_slice(bytes);
            at += bytes.len();
        };
        put(&self.tau.to_le_bytes());
        put(&self.g.to_le_bytes());
        put(&self.albedo.to_le_bytes());
        put(&self.n.to_le_bytes());
        for v in [self.cos_theta, self.beta, self.alpha]
            .iter()
            .chain(&self.ev_pos)
            .chain(&self.ev_dir)
        {
            put(&v.to_le_bytes());
        }
    }

    pub fn decode(b: &[u8; ROW_BYTES]) -> Self {
        let f32_at = |i: usize| f32::from_le_bytes(b[i..i + 4].try_into().unwrap());
        let v3 = |i: usize| [f32_at(i), f32_at(i + 4), f32_at(i + 8)];
        Self {
            tau: f32_at(0),
            g: f32_at(4),
            albedo: f64::from_le_bytes(b[8..16].try_into().unwrap()),
            n: u32::from_le_bytes(b[16..20].try_into().unwrap()),
            cos_theta: f32_at(20),
            beta: f32_at(24),
            alpha: f32_at(28),
            ev_pos: v3(32),
            ev_dir: v3(44),
        }
    }

    /// Checks the invariants every valid row satisfies (with f32 rounding slack).
    pub fn validate(&self) -> Result<(), String> {
        const SLACK: f32 = 1e-5;
        let all = [
            self.tau,
            self.g,
            self.cos_theta,
            self.beta,
            self.alpha,
            self.ev_pos[0],
            self.ev_pos[1],
            self.ev_pos[2],
            self.ev_dir[0],
            self.ev_dir[1],
            self.ev_dir[2],
        ];
        if !all.iter().all(|v| v.is_finite()) || !self.albedo.is_finite() {
            return Err("non-finite value".into());
        }
        if self.n == 0 {
            return Err("n = 0 (every walk has at least the centre event)".into());
        }
        if !(0.0..=crate::ranges::TAU_LIMIT as f32).contains(&self.tau) {
            return Err(format!(
                "tau = {} outside {}",
                self.tau,
                crate::ranges::TAU_RANGE
            ));
        }
        // Exact: the simulator clamps g to ±G_MAX before storing it in f32, and the model
        // file's check of the training range (G_MAX + 1e-6) must pass whatever rows pass.
        if self.g.abs() > crate::ranges::G_MAX as f32 {
            return Err(format!("g = {} outside {}", self.g, crate::ranges::G_RANGE));
        }
        if !(0.0..=1.0).contains(&self.albedo) {
            return Err(format!("albedo = {} outside [0, 1]", self.albedo));
        }
        if self.cos_theta.abs() > 1.0 + SLACK
            || self.alpha * self.alpha + self.beta * self.beta > 1.0 + SLACK
        {
            return Err("exit outside the unit sphere / unit disk".into());
        }
        let len2 = |v: [f32; 3]| v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
        if len2(self.ev_pos) > 1.0 + SLACK || (len2(self.ev_dir) - 1.0).abs() > 1e-4 {
            return Err("representative event outside the unit ball or |W| != 1".into());
        }
        Ok(())
    }

    /// A row from one CSV line in [`COLUMNS`] order ([`Self::write_csv`]'s), checked as a
    /// binary row is ([`Self::validate`]): `merge` refuses an edited or foreign CSV row
    /// with the column and its range instead of joining it.
    pub fn parse_csv(line: &str) -> Result<Self, String> {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != COLUMNS.len() {
            return Err(format!(
                "expected {} comma-separated numbers ({}), found {} fields (truncated or not \
                 a walk row)",
                COLUMNS.len(),
                COLUMNS.join(","),
                fields.len()
            ));
        }
        // Each column parsed in its own type (as `decode` reads it), so that a value beyond
        // f32 (1e39) is named here rather than turning into infinity.
        let num = |i: usize| finite_field::<f64>(&fields, i);
        let f = |i: usize| finite_field::<f32>(&fields, i);
        let n = fields[3].parse::<u32>().map_err(|_| {
            format!(
                "n = {:?} is not a whole number of events in [1, {}]",
                fields[3],
                u32::MAX
            )
        })?;
        let row = Self {
            tau: f(0)?,
            g: f(1)?,
            albedo: num(2)?,
            n,
            cos_theta: f(4)?,
            beta: f(5)?,
            alpha: f(6)?,
            ev_pos: [f(7)?, f(8)?, f(9)?],
            ev_dir: [f(10)?, f(11)?, f(12)?],
        };
        row.validate()?;
        Ok(row)
    }

    /// One CSV line in [`COLUMNS`] order, each number short and exact (`ranges::Short`).
    pub fn write_csv(&self, w: &mut impl Write) -> io::Result<()> {
        let [x, y, z] = self.ev_pos;
        let [wx, wy, wz] = self.ev_dir;
        writeln!(
            w,
            "{},{},{},{},{},{},{},{},{},{},{},{},{}",
            Short(self.tau),
            Short(self.g),
            Short(self.albedo),
            self.n,
            Short(self.cos_theta),
            Short(self.beta),
            Short(self.alpha),
            Short(x),
            Short(y),
            Short(z),
            Short(wx),
            Short(wy),
            Short(wz)
        )
    }
}

/// Field i of a CSV row as a finite T, or the error naming its column.
fn finite_field<T: std::str::FromStr + Copy + Into<f64>>(
    fields: &[&str],
    i: usize,
) -> Result<T, String> {
    if let Some(v) = fields[i]
        .parse::<T>()
        .ok()
        .filter(|v| (*v).into().is_finite())
    {
        return Ok(v);
    }
    // A finite number that T cannot hold (1e308 in an f32 column) is out of the column's
    // range, not "not a finite number".
    if fields[i].parse::<f64>().is_ok_and(f64::is_finite) {
        return Err(format!(
            "{} = {} is out of range (beyond f32, whose largest is 3.4e38)",
            COLUMNS[i], fields[i]
        ));
    }
    Err(format!(
        "{} = {:?} is not a finite number",
        COLUMNS[i], fields[i]
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_row() -> Row {
        Row {
            tau: 5.0,
            g: 0.875,
            albedo: 0.999_99,
            n: 42,
            cos_theta: 0.25,
            beta: -0.5,
            alpha: 0.125,
            ev_pos: [0.1, -0.2, 0.3],
            ev_dir: [0.6, 0.0, 0.8],
        }
    }

    /// A row written as CSV reads back the same (shortest round-trip formatting).
    #[test]
    fn csv_rows_round_trip() {
        let row = sample_row();
        let mut line = Vec::new();
        row.write_csv(&mut line).unwrap();
        let line = String::from_utf8(line).unwrap();
        assert_eq!(Row::parse_csv(line.trim_end()).unwrap(), row);
    }

    /// Tiny and huge values are written with an exponent and read back exactly; −0 is
    /// written 0 (in every column); ordinary values keep their plain digits.
    #[test]
    fn csv_numbers_are_short_and_exact() {
        let row = Row {
            tau: -0.0,
            albedo: 1e-300,
            cos_theta: 3.5e-6,
            beta: f32::MIN_POSITIVE,
            ..sample_row()
        };
        let mut line = Vec::new();
        row.write_csv(&mut line).unwrap();
        let line = String::from_utf8(line).unwrap();
        let fields: Vec<&str> = line.trim_end().split(',').collect();
        assert_eq!(
            fields[..7],
            [
                "0",
                "0.875",
                "1e-300",
                "42",
                "3.5e-6",
                "1.1754944e-38",
                "0.125"
            ]
        );
        assert!(line.len() < 100, "{line}");
        let back = Row::parse_csv(line.trim_end()).unwrap();
        assert_eq!(back, Row { tau: 0.0, ..row });
        assert_eq!(format!("{}", Short(2.5e16f64)), "2.5e16");
        assert_eq!(format!("{}", Short(123456.75f32)), "123456.75");
    }

    /// NaN in any column (a foreign binary row with a right checksum) is refused by the
    /// finiteness check: the range checks after it are comparisons that NaN passes.
    #[test]
    fn nan_in_any_column_is_refused() {
        for k in 0..11 {
            let mut r = sample_row();
            let v = match k {
                0 => &mut r.tau,
                1 => &mut r.g,
                2 => &mut r.cos_theta,
                3 => &mut r.beta,
                4 => &mut r.alpha,
                5..=7 => &mut r.ev_pos[k - 5],
                _ => &mut r.ev_dir[k - 8],
            };
            *v = f32::NAN;
            assert_eq!(
                r.validate(),
                Err("non-finite value".to_string()),
                "f32 column {k}"
            );
        }
        let r = Row {
            albedo: f64::NAN,
            ..sample_row()
        };
        assert_eq!(r.validate(), Err("non-finite value".to_string()));
    }

    /// Each column out of its range (or not a number) is refused, naming the column.
    #[test]
    fn csv_rows_out_of_range_are_refused() {
        let mut line = Vec::new();
        sample_row().write_csv(&mut line).unwrap();
        let good: Vec<String> = String::from_utf8(line)
            .unwrap()
            .trim_end()
            .split(',')
            .map(str::to_string)
            .collect();
        for (col, bad, says) in [
            (0, "-5", "tau"),
            (1, "7.5", "g"),
            (2, "2.0", "albedo"),
            (3, "-1", "n = "),
            (3, "2.5", "n = "),
            (3, "0", "n = 0"),
            (4, "7", "exit"),
            // Negative values out of range, and each exit-disk column, are refused too.
            (4, "-7", "exit"),
            (1, "-7.5", "g = -7.5"),
            (5, "2", "exit"),
            (6, "-2", "exit"),
            (7, "1e30", "event"),
            (7, "1e39", "ev_x = 1e39 is out of range (beyond f32"),
            (0, "1e308", "tau = 1e308 is out of range (beyond f32"),
            (0, "inf", "tau = \"inf\" is not a finite number"),
            (10, "nan", "ev_wx"),
            // W = (0, 0, 0.8), |W|² = 0.64: too short as well as too long is refused.
            (10, "0", "event"),
            (10, "0.7", "event"),
        ] {
            let mut fields = good.clone();
            fields[col] = bad.to_string();
            let e = Row::parse_csv(&fields.join(",")).expect_err(bad);
            assert!(e.contains(says), "column {col} = {bad}: {e}");
        }
        assert!(
            Row::parse_csv("1,2,3")
                .unwrap_err()
                .contains("found 3 fields")
        );
    }

    /// g is held to ±G_MAX as f32 exactly, what the simulator stores: a row just beyond it
    /// used to pass here and fail the model file's training-range check after training.
    #[test]
    fn g_is_held_to_its_stored_limit() {
        let at = |g: f32| Row { g, ..sample_row() }.validate();
        assert!(at(crate::ranges::G_MAX as f32).is_ok());
        assert!(at(-(crate::ranges::G_MAX as f32)).is_ok());
        assert!(at(0.999_01).is_err());
        assert!(at(f32::from_bits((crate::ranges::G_MAX as f32).to_bits() + 1)).is_err());
    }

    /// Row::new puts each quantity of the walk in its own column, with its own sign, and
    /// keeps φ in f64. The dataset tests only compare rows with rows made by this same
    /// function (walk_row), so a column fed the wrong quantity passed them; α with the
    /// wrong sign passes every marginal statistic too (its law is symmetric about 0 by the
    /// mirror symmetry x → −x), while it breaks α's pairing with the event (ev_x, ev_wx)
    /// that EventGen learns. Every value below differs from every other, and each is
    /// exact in f32 except ev_dir's, which are compared with their own f32 roundings.
    #[test]
    fn a_rows_columns_are_its_walks_quantities() {
        let c = crate::conditions::Conditions {
            tau: 7.5,
            g: -0.25,
            albedo: 0.999_999_3,
        };
        let w = crate::walk::CanonicalWalk {
            n: 17,
            exit: crate::frame::CanonicalExit {
                cos_theta: -0.375,
                alpha: 0.5,
                beta: -0.625,
            },
            event_pos: glam::DVec3::new(0.125, -0.1875, 0.4375),
            // A unit vector: 0.2304 + 0.36 + 0.4096 = 1.
            event_dir: glam::DVec3::new(0.48, -0.6, 0.64),
        };
        let r = Row::new(c, &w);
        assert_eq!(
            r,
            Row {
                tau: 7.5,
                g: -0.25,
                albedo: 0.999_999_3,
                n: 17,
                cos_theta: -0.375,
                beta: -0.625,
                alpha: 0.5,
                ev_pos: [0.125, -0.1875, 0.4375],
                ev_dir: [0.48f64 as f32, -0.6f64 as f32, 0.64f64 as f32],
            }
        );
        r.validate().unwrap();
    }

    /// A negative albedo is refused, directly and in a CSV row as `merge` reads one: only
    /// φ > 1 was ever tried (2.0 above), so a check of the upper bound alone passed. Both
    /// bounds are albedos (φ = 0: everything absorbed; φ = 1: nothing).
    #[test]
    fn a_negative_albedo_is_refused() {
        let at = |albedo: f64| Row {
            albedo,
            ..sample_row()
        };
        assert!(at(0.0).validate().is_ok());
        assert!(at(1.0).validate().is_ok());
        let e = at(-0.25).validate().unwrap_err();
        assert!(e.contains("albedo = -0.25 outside [0, 1]"), "{e}");
        let mut line = Vec::new();
        at(-0.25).write_csv(&mut line).unwrap();
        let line = String::from_utf8(line).unwrap();
        let e = Row::parse_csv(line.trim_end()).unwrap_err();
        assert!(e.contains("albedo = -0.25 outside [0, 1]"), "{line}: {e}");
    }

    /// τ is held to TAU_LIMIT (1000) from above as well as to 0 from below: only −5 and
    /// values beyond f32 were tried, so a row of τ = 1500 (an edited CSV, a foreign file)
    /// passed a check of the lower bound alone, and a model trained on it failed the model
    /// file's training-range check (hi ≤ TAU_LIMIT) only after the training.
    #[test]
    fn tau_beyond_its_limit_is_refused() {
        let limit = crate::ranges::TAU_LIMIT as f32;
        let at = |tau: f32| Row {
            tau,
            ..sample_row()
        };
        assert!(at(limit).validate().is_ok());
        // The next f32 above the limit.
        assert!(at(f32::from_bits(limit.to_bits() + 1)).validate().is_err());
        let e = at(1500.0).validate().unwrap_err();
        assert!(e.contains("tau = 1500 outside [0, 1000]"), "{e}");
        let mut line = Vec::new();
        at(1500.0).write_csv(&mut line).unwrap();
        let line = String::from_utf8(line).unwrap();
        let e = Row::parse_csv(line.trim_end()).unwrap_err();
        assert!(e.contains("tau = 1500 outside [0, 1000]"), "{line}: {e}");
    }
}
