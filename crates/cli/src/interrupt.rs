//! Ctrl-C as a request to stop cleanly: long loops poll the flag, return an error, and
//! their temporary output files are removed as they are dropped.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};

static FLAG: AtomicBool = AtomicBool::new(false);
static INSTALLED: OnceLock<()> = OnceLock::new();

/// Installs the handler (once) and returns the flag to poll.
pub fn flag() -> &'static AtomicBool {
    INSTALLED.get_or_init(|| {
        let _ = ctrlc::set_handler(|| {
            if FLAG.swap(true, Ordering::SeqCst) {
                // Second Ctrl-C: the user means it.
                std::process::exit(130);
            }
            eprintln!("\ninterrupt: stopping at the next safe point (Ctrl-C again to abort)");
        });
    });
    &FLAG
}

pub fn requested() -> bool {
    FLAG.load(Ordering::SeqCst)
}
