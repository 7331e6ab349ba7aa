//! Progress bars in one style.

use indicatif::{ProgressBar, ProgressState, ProgressStyle};

/// A bar over `len` items of `unit`, with rate, ETA and a free message (e.g. events/s).
pub fn bar(len: u64, unit: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
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
/// clears it when the render is done, so only the tables stay; drawn only on a terminal.
pub fn render_bar(label: &str, pixels: u64, o: &render_gpu::render::RenderOptions) -> ProgressBar {
    if let Some(b) = o.time_budget {
        return spinner(&format!("{label}, {b} s"));
    }
    let pb = bar(pixels * o.spp as u64, "samples");
    pb.set_message(label.to_string());
    pb
}

/// A spinner with elapsed time for work of unknown length (e.g. building a distance grid,
/// 15 s for a fine one, which showed nothing at all); drawn only on a terminal.
pub fn spinner(msg: &str) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    pb.set_style(
        ProgressStyle::with_template("{spinner} {msg} ({elapsed})").expect("valid template"),
    );
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

/// "1 walk", "2 walks": a count with its noun.
pub fn count(n: u64, noun: &str) -> String {
    if n == 1 {
        format!("1 {noun}")
    } else {
        format!("{n} {noun}s")
    }
}
