//! Helpers shared by the CLI tests that run the binary in a scratch directory.

// Each test file uses a part of this module; the rest is compiled unused there.
#![allow(dead_code)]

use std::path::Path;
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};

/// Writes `header` and `rows` as a binary dataset at `path`: a file as another build or
/// format version would have written it (its pieces edited), with a valid checksum.
pub fn write_dataset(
    path: &Path,
    header: scatter_sim::dataset::Header,
    rows: &[scatter_sim::dataset::Row],
) {
    let mut sink = scatter_sim::dataset::create_sink(path, header).unwrap();
    for row in rows {
        sink.push(row).unwrap();
    }
    sink.finish().unwrap();
}

/// The dataset `from` written to `to` with its header edited by `edit` (rows kept).
pub fn rewrite_dataset(
    from: &Path,
    to: &Path,
    edit: impl FnOnce(&mut scatter_sim::dataset::Header),
) {
    let (mut header, rows) = scatter_sim::dataset::read_dataset(from).unwrap();
    edit(&mut header);
    write_dataset(to, header, &rows);
}

/// Runs `stcvae args…` with `dir` as the current directory.
pub fn stcvae(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run stcvae")
}

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// The words of a command line (for argument lists without quoted spaces).
pub fn words(line: &str) -> Vec<&str> {
    line.split_whitespace().collect()
}

/// Ctrl-C for `child` once `started()` holds and `settle` more has passed: mid-work, not
/// before the command has begun. The ten minutes allowed for the start only keep a command
/// that never starts from hanging the suite; they time nothing (a loaded machine, e.g. one
/// building in parallel, starts the binary in seconds).
///
/// With `signals` 2, a second SIGINT follows microseconds after the first, as `timeout`
/// sends one to a process and one to its group. It is sent to the main thread (tgkill), so
/// the kernel keeps it pending apart from the first (process-directed) one instead of
/// merging the two, and the handler sees two signals; a second `kill` process could start
/// more than the CLI's 300 ms same-request window later on a loaded machine. (Other Unix
/// systems get two process-directed signals, which the kernel may merge into one.) With
/// `signals` 0 it only waits.
#[cfg(unix)]
pub fn interrupt_when(
    child: &Child,
    started: impl Fn() -> bool,
    settle: Duration,
    signals: usize,
    what: &str,
) {
    let start = Instant::now();
    while !started() {
        assert!(
            start.elapsed() < Duration::from_secs(600),
            "{what}: never started"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(settle);
    assert!(signals <= 2, "{what}: {signals} signals");
    if signals == 0 {
        return;
    }
    let pid = child.id() as libc::pid_t;
    // SAFETY: plain system calls on a child process this test owns and has not reaped.
    let sent = unsafe { libc::kill(pid, libc::SIGINT) };
    assert_eq!(sent, 0, "{what}: kill failed");
    if signals == 2 {
        // SAFETY: as above; on Linux the main thread's id is the process id.
        #[cfg(target_os = "linux")]
        let sent = unsafe { libc::syscall(libc::SYS_tgkill, pid, pid, libc::SIGINT) };
        #[cfg(not(target_os = "linux"))]
        let sent = unsafe { libc::kill(pid, libc::SIGINT) };
        assert_eq!(sent, 0, "{what}: second signal failed");
    }
}

/// Waits until `child` has a handler for SIGINT (the `SigCgt` mask of its
/// /proc/PID/status), so that a signal sent now tests the handling rather than the race
/// with its installation. False when the child exits first: it never caught SIGINT.
#[cfg(target_os = "linux")]
pub fn wait_for_sigint_handler(child: &Child) -> bool {
    let status = format!("/proc/{}/status", child.id());
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(600) {
        let Ok(text) = std::fs::read_to_string(&status) else {
            return false;
        };
        // A zombie (exited, not yet reaped) still has a status file, with State Z.
        if text
            .lines()
            .any(|l| l.starts_with("State:") && l.contains('Z'))
        {
            return false;
        }
        let caught = text
            .lines()
            .find_map(|l| l.strip_prefix("SigCgt:"))
            .and_then(|m| u64::from_str_radix(m.trim(), 16).ok())
            .unwrap_or(0);
        // Bit n−1 is signal n; SIGINT is 2.
        if caught & (1 << (libc::SIGINT - 1)) != 0 {
            return true;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    false
}

/// Whether `out` of a GPU command failed only for want of a Vulkan adapter here, outside
/// CI, where the test is then skipped with the reason said ([`skip`]); under CI, where
/// lavapipe is installed, never.
pub fn skipped_without_vulkan(out: &Output, test: &str) -> bool {
    let err = String::from_utf8_lossy(&out.stderr);
    let skip_it = !out.status.success()
        && err.contains("no wgpu adapter")
        && std::env::var_os("CI").is_none();
    if skip_it {
        skip(&format!("{test}: {err}"));
    }
    skip_it
}

/// Says on the terminal why a test is skipped. Written to stderr directly rather than with
/// `eprintln!`, which libtest captures and shows only for failing tests: a skipped test
/// passes, so its reason would otherwise never be seen without `--nocapture`.
pub fn skip(reason: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "skipping {reason}");
}

/// The PNG at `path`: its width, height and pixel bytes (failing with the file's name).
pub fn read_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let f = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut dec = png::Decoder::new(std::io::BufReader::new(f))
        .read_info()
        .unwrap_or_else(|e| panic!("{}: not a PNG: {e}", path.display()));
    let mut buf = vec![0; dec.output_buffer_size()];
    let info = dec
        .next_frame(&mut buf)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    (info.width, info.height, buf)
}
