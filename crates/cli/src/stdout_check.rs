//! Standard output's write errors, kept for the exit status. The print macros (main.rs)
//! drop what cannot be written rather than panic, and so dropped a full disk's error too:
//! `stcvae eval … > table.md` on a full disk, or `bench sim > /dev/full`, cut the table
//! short and exited 0 without a word.

use std::sync::OnceLock;

/// The first write error on standard output, as the OS words it.
static FAILED: OnceLock<String> = OnceLock::new();

/// Records a failed write to standard output. A closed pipe is not: it is a request to stop
/// (interrupt::stop_on_closed_pipe; `bench … | head -1` ends quietly), and once Ctrl-C has
/// taken the terminal's pipe with it, the text is dropped on purpose.
pub fn failed(e: &std::io::Error) {
    if e.kind() != std::io::ErrorKind::BrokenPipe {
        let _ = FAILED.set(e.to_string());
    }
}

/// The command's error when standard output lost any text (what is still buffered is
/// written first, so that its error counts too).
pub fn check() -> anyhow::Result<()> {
    use std::io::Write as _;
    if let Err(e) = std::io::stdout().flush() {
        failed(&e);
    }
    match FAILED.get() {
        Some(e) => anyhow::bail!("cannot write standard output (its text is cut short): {e}"),
        None => Ok(()),
    }
}
