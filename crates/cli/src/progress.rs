//! Progress bars in one style: drawn on a terminal, and written as plain lines now and
//! then where stderr is a file or a pipe (a batch job's log).

use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressState, ProgressStyle, TermLike};

/// Where bars draw. On a terminal, as usual; otherwise indicatif draws nothing at all, and
/// an hour of training under a scheduler logged nothing between its first and last lines,
/// so the bars' lines are written plainly every `STCVAE_LOG_PROGRESS_EVERY` seconds
/// (default 30; none in the first interval, so short commands stay quiet).
pub fn target() -> ProgressDrawTarget {
    if std::io::stderr().is_terminal() {
        return ProgressDrawTarget::stderr();
    }
    // Unreadable or negative: the default, said once (it was ignored without a word);
    // beyond any Duration: never.
    let raw = std::env::var("STCVAE_LOG_PROGRESS_EVERY").ok();
    let parsed = raw
        .as_deref()
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|s| *s >= 0.0);
    if let Some(v) = raw.as_deref().filter(|v| !v.is_empty())
        && parsed.is_none()
    {
        static WARNED: std::sync::Once = std::sync::Once::new();
        WARNED.call_once(|| {
            eprintln!(
                "warning: STCVAE_LOG_PROGRESS_EVERY = {v:?} is not a number of seconds >= 0: \
                 progress is logged every 30 s"
            )
        });
    }
    let every = parsed.map_or(Duration::from_secs(30), |s| {
        Duration::try_from_secs_f64(s).unwrap_or(Duration::MAX)
    });
    ProgressDrawTarget::term_like_with_hz(
        Box::new(LogLines {
            every,
            state: Mutex::new(LogState {
                last: Instant::now(),
                lines: Vec::new(),
                written: Vec::new(),
            }),
        }),
        1,
    )
}

/// A "terminal" that keeps each draw's lines and writes them, one per line, when the
/// interval since the last written draw (or the start) has passed.
#[derive(Debug)]
struct LogLines {
    every: Duration,
    state: Mutex<LogState>,
}

#[derive(Debug)]
struct LogState {
    last: Instant,
    lines: Vec<String>,
    /// The draw written last: the same lines again (a spinner's message between its
    /// ticks) are not written twice.
    written: Vec<String>,
}

impl TermLike for LogLines {
    fn width(&self) -> u16 {
        100
    }
    fn move_cursor_up(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_down(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_right(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_left(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn write_line(&self, s: &str) -> std::io::Result<()> {
        self.write_str(s)
    }
    /// indicatif writes each line, then spaces to the line's end: only text is kept.
    fn write_str(&self, s: &str) -> std::io::Result<()> {
        let text = s.trim();
        if !text.is_empty() {
            let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
            st.lines.push(text.to_string());
        }
        Ok(())
    }
    fn clear_line(&self) -> std::io::Result<()> {
        Ok(())
    }
    fn flush(&self) -> std::io::Result<()> {
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let lines = std::mem::take(&mut st.lines);
        if !lines.is_empty() && lines != st.written && st.last.elapsed() >= self.every {
            st.last = Instant::now();
            eprintln!("{}", lines.join("\n"));
            st.written = lines;
        }
        Ok(())
    }
}

/// A bar over `len` items of `unit`, with rate, ETA and a free message (e.g. events/s).
pub fn bar(len: u64, unit: &str) -> ProgressBar {
    let pb = ProgressBar::with_draw_target(Some(len), target());
    pb.set_style(
        ProgressStyle::with_template(&format!(
            "{{elapsed_precise}} [{{wide_bar}}] {{human_pos}}/{{human_len}} {unit} ({{rate}}, ETA {{eta}}) {{msg}}"
        ))
        .expect("valid template")
        // indicatif's own {per_sec} prints four decimals ("695,561.7692/s").
        .with_key("rate", |s: &ProgressState, w: &mut dyn std::fmt::Write| {
            let _ = write!(w, "{}/s", si(s.per_sec()));
        })
        .progress_chars("=> "),
    );
    pb
}

/// The progress of one render of `pixels` pixels, named by `label` (e.g. "stcvae, seed
/// 2"), for the commands that render many images: a bench row at high density runs for half
/// an hour, and showed nothing until its row was printed. A bar over its samples, or a
/// spinner with its budget for a render against the clock (no known length). The caller
/// clears it when the render is done, so only the tables stay; drawn on a terminal, written
/// now and then to a log ([`target`]).
pub fn render_bar(label: &str, pixels: u64, o: &render_gpu::render::RenderOptions) -> ProgressBar {
    if let Some(b) = o.time_budget {
        return spinner(&format!("{label}, {} s", scatter_sim::ranges::num(b)));
    }
    let pb = bar(pixels * o.spp as u64, "samples");
    pb.set_message(label.to_string());
    pb
}

/// A spinner with elapsed time for work of unknown length (e.g. building a distance grid,
/// 15 s for a fine one, which showed nothing at all); drawn on a terminal, written now and
/// then to a log ([`target`]).
pub fn spinner(msg: &str) -> ProgressBar {
    let pb = ProgressBar::with_draw_target(None, target());
    // The spinning glyph means nothing in a log's lines.
    let template = if std::io::stderr().is_terminal() {
        "{spinner} {msg} ({elapsed})"
    } else {
        "{msg} ({elapsed})"
    };
    pb.set_style(ProgressStyle::with_template(template).expect("valid template"));
    pb.set_message(msg.to_string());
    pb.enable_steady_tick(std::time::Duration::from_millis(120));
    pb
}

/// Human-readable rate, e.g. "12.30 M" or "553.50"; the caller adds a space and the unit.
pub fn si(x: f64) -> String {
    let (v, p) = if x >= 1e9 {
        (x / 1e9, "G")
    } else if x >= 1e6 {
        (x / 1e6, "M")
    } else if x >= 1e3 {
        (x / 1e3, "k")
    } else {
        (x, "")
    };
    // No space left dangling after a plain number ("553.50 paths/s", not "553.50  paths/s").
    if p.is_empty() {
        format!("{v:.2}")
    } else {
        format!("{v:.2} {p}")
    }
}

/// A number to 4 significant digits: 0.001953 and 13.83, not 0.002 and 13.8275 (fixed
/// decimals hid an absorption's doubling, printed small times as 0.00 beside their
/// ratios, and gave ratios more digits than their times); beyond [1e-3, 1e4) in exponent
/// form.
pub fn significant4(v: f64) -> String {
    if !v.is_finite() || v == 0.0 {
        return format!("{v}");
    }
    if v.abs() >= 1e4 || v.abs() < 1e-3 {
        return format!("{v:.3e}");
    }
    let decimals = (3 - v.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{v:.decimals$}");
    // 9999.6 rounds to 5 digits.
    if s.trim_start_matches('-').len() > 4 && !s.contains('.') {
        return format!("{v:.3e}");
    }
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// "1 walk", "2 walks": a count with its noun.
pub fn count(n: u64, noun: &str) -> String {
    if n == 1 {
        format!("1 {noun}")
    } else {
        format!("{n} {noun}s")
    }
}

#[cfg(test)]
mod tests {
    use super::{LogLines, LogState, si, significant4};
    use indicatif::TermLike;
    use std::sync::Mutex;
    use std::time::{Duration, Instant};

    #[test]
    fn numbers_keep_four_significant_digits() {
        for (v, want) in [
            (0.001953125, "0.001953"),
            (13.827, "13.83"),
            (0.0475, "0.0475"),
            (128.0, "128"),
            (9999.4, "9999"),
            (9999.6, "1.000e4"),
            (1e-4, "1.000e-4"),
            (12346.0, "1.235e4"),
            (-0.5, "-0.5"),
            (0.0, "0"),
            // Negative values take their decimals from |v| (log10 of v is NaN).
            (-13.827, "-13.83"),
            (-9999.4, "-9999"),
            (-1234.0, "-1234"),
            // The lower end of the plain range is included.
            (0.001, "0.001"),
        ] {
            assert_eq!(significant4(v), want, "{v}");
        }
    }

    #[test]
    fn rates_take_k_m_and_g() {
        assert_eq!(si(2.5e9), "2.50 G");
        assert_eq!(si(1e9), "1.00 G");
        assert_eq!(si(12.3e6), "12.30 M");
        assert_eq!(si(4.2e3), "4.20 k");
        assert_eq!(si(553.5), "553.50");
    }

    /// A log's draw that repeats the one written last is not written again (a spinner's
    /// message between ticks), and the interval is counted from the last written one. The
    /// 5 ms sleep only makes the two instants differ.
    #[test]
    fn a_draw_like_the_last_written_is_not_written_again() {
        let t = LogLines {
            every: Duration::ZERO,
            state: Mutex::new(LogState {
                last: Instant::now(),
                lines: Vec::new(),
                written: Vec::new(),
            }),
        };
        t.write_line("a   ").unwrap();
        t.flush().unwrap();
        assert_eq!(t.state.lock().unwrap().written, ["a"]);
        let first = t.state.lock().unwrap().last;
        std::thread::sleep(Duration::from_millis(5));
        t.write_line("a").unwrap();
        t.flush().unwrap();
        assert_eq!(
            t.state.lock().unwrap().last,
            first,
            "the same draw written again"
        );
        t.write_line("b").unwrap();
        t.flush().unwrap();
        assert_eq!(t.state.lock().unwrap().written, ["b"]);
    }
}
