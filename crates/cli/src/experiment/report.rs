//! `report.md` and `figures.csv` of an experiment.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Result;

use super::{Args, Config};
use crate::device::Engine;

/// A cell of the figures table: a number (written with full precision in the CSV) or text.
pub enum Cell {
    Num(f64),
    Text(String),
}

/// A bound that could not be resolved reads as such (not as 0, nor as NaN).
impl From<Option<f64>> for Cell {
    fn from(v: Option<f64>) -> Self {
        v.map_or(Cell::Text("not resolved".into()), Cell::Num)
    }
}

impl From<f64> for Cell {
    fn from(v: f64) -> Self {
        Cell::Num(v)
    }
}
impl From<&str> for Cell {
    fn from(v: &str) -> Self {
        Cell::Text(v.to_string())
    }
}
impl From<String> for Cell {
    fn from(v: String) -> Self {
        Cell::Text(v)
    }
}

pub struct Report {
    pub md: String,
    header: Vec<String>,
    rows: Vec<Vec<Cell>>,
}

/// Days since 1970-01-01 to (y, m, d) (Howard Hinnant's civil_from_days).
fn civil(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

pub fn today() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    let (y, m, d) = civil(secs.div_euclid(86_400));
    format!("{y:04}-{m:02}-{d:02}")
}

/// `text` as a Markdown code span: fenced by one backtick more than its longest run of
/// them, so that a path holding a backtick does not end the span early.
fn code_span(text: &str) -> String {
    let longest = text.split(|c| c != '`').map(str::len).max().unwrap_or(0);
    let fence = "`".repeat(longest + 1);
    let pad = if text.starts_with('`') || text.ends_with('`') {
        " "
    } else {
        ""
    };
    format!("{fence}{pad}{text}{pad}{fence}")
}

impl Report {
    pub fn new(cfg: &Config, a: &Args, engine: &Engine) -> Self {
        let mut md = String::new();
        let _ = writeln!(md, "# {}\n", cfg.title);
        if !cfg.description.is_empty() {
            let _ = writeln!(md, "{}\n", cfg.description.trim());
        }
        let word = crate::paths::shell_word;
        let command = format!(
            "stcvae experiment {}{}{}{}{}",
            word(&a.config),
            if a.quick { " --quick" } else { "" },
            match a.device {
                crate::device::DeviceArg::Auto => "",
                crate::device::DeviceArg::Gpu => " --device gpu",
                crate::device::DeviceArg::Cpu => " --device cpu",
            },
            // The model is part of what was measured, and the folder of where it went.
            a.model
                .as_ref()
                .map_or(String::new(), |m| format!(" --model {}", word(m))),
            if a.out == std::path::Path::new(super::DEFAULT_OUT) {
                String::new()
            } else {
                format!(" --out {}", word(&a.out))
            },
        );
        let _ = writeln!(
            md,
            "Regenerate: {}  \nMachine: {} logical cores, {}; date {}.{}\n",
            code_span(&command),
            std::thread::available_parallelism().map_or(0, |n| n.get()),
            engine.describe(),
            today(),
            if a.quick {
                " **Quick version** (small images, few samples): the numbers are noisy."
            } else {
                ""
            }
        );
        Self {
            md,
            header: Vec::new(),
            rows: Vec::new(),
        }
    }

    pub fn columns(&mut self, names: &[&str]) {
        self.header = names.iter().map(|s| s.to_string()).collect();
    }

    pub fn row(&mut self, cells: Vec<Cell>) {
        self.rows.push(cells);
    }

    pub fn text(&mut self, s: &str) {
        self.md.push_str(s);
        self.md.push('\n');
    }

    pub fn image(&mut self, caption: &str, file: &str) {
        let _ = writeln!(self.md, "![{caption}]({file})  \n*{caption}*\n");
    }

    /// The figures table as markdown (numbers to 4 significant digits).
    pub fn table(&mut self) {
        let _ = writeln!(self.md, "| {} |", self.header.join(" | "));
        let _ = writeln!(self.md, "|{}|", vec!["---"; self.header.len()].join("|"));
        for r in &self.rows {
            let cells: Vec<String> = r
                .iter()
                .map(|c| match c {
                    Cell::Num(v) => crate::progress::significant4(*v),
                    Cell::Text(t) => t.clone(),
                })
                .collect();
            let _ = writeln!(self.md, "| {} |", cells.join(" | "));
        }
        self.md.push('\n');
    }

    pub fn write(&self, dir: &Path) -> Result<()> {
        let mut csv = self.header.join(",");
        csv.push('\n');
        for r in &self.rows {
            let cells: Vec<String> = r
                .iter()
                .map(|c| match c {
                    Cell::Num(v) => format!("{v}"),
                    Cell::Text(t) => csv_field(t),
                })
                .collect();
            csv.push_str(&cells.join(","));
            csv.push('\n');
        }
        let (csv_path, md_path) = (dir.join("figures.csv"), dir.join("report.md"));
        scatter_sim::output::write_atomic_set(&[
            (&csv_path, csv.as_bytes()),
            (&md_path, self.md.as_bytes()),
        ])
        .map_err(|(path, e)| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
        Ok(())
    }
}

/// A CSV field as RFC 4180 has it: quoted where it holds a comma, a quote or a line
/// break (commas were replaced by semicolons, so labels differed from the report's).
fn csv_field(t: &str) -> String {
    if t.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", t.replace('"', "\"\""))
    } else {
        t.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::{code_span, csv_field};

    #[test]
    fn csv_fields_are_quoted_where_needed() {
        assert_eq!(csv_field("PT, no NEE"), "\"PT, no NEE\"");
        assert_eq!(csv_field("a \"b\""), "\"a \"\"b\"\"\"");
        assert_eq!(csv_field("ST-CVAE"), "ST-CVAE");
    }

    /// The report's command, pasted into a shell, runs the same experiment: paths with
    /// spaces, quotes or a leading dash are quoted (`--out out dir/x'y` ran another
    /// command), and a backtick does not end the Markdown span early.
    #[test]
    fn the_regenerate_command_survives_odd_paths() {
        use crate::paths::shell_word;
        use std::path::Path;
        assert_eq!(shell_word(Path::new("configs/t.toml")), "configs/t.toml");
        assert_eq!(shell_word(Path::new("my teaser.toml")), "'my teaser.toml'");
        assert_eq!(shell_word(Path::new("out dir/x'y")), "'out dir/x'\\''y'");
        assert_eq!(shell_word(Path::new("-x")), "./-x");
        assert_eq!(shell_word(Path::new("")), "''");
        assert_eq!(code_span("stcvae experiment a"), "`stcvae experiment a`");
        assert_eq!(code_span("a `b` c"), "``a `b` c``");
        assert_eq!(code_span("x``y`"), "``` x``y` ```");
    }

    /// Days since 1970-01-01 to the civil date, the report's "date": the epoch itself, a
    /// leap day, the last day of a year and New Year's days (January and February are
    /// the end of the algorithm's March-based year, so their year is one on). The day
    /// counts are Python's `(date(y, m, d) - date(1970, 1, 1)).days`.
    #[test]
    fn days_since_the_epoch_are_civil_dates() {
        for (days, date) in [
            (0, (1970, 1, 1)),
            (10_957, (2000, 1, 1)),
            (19_782, (2024, 2, 29)),
            (20_454, (2026, 1, 1)),
            (20_818, (2026, 12, 31)),
        ] {
            assert_eq!(super::civil(days), date, "day {days}");
        }
    }
}
