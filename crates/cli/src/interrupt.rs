//! Ctrl-C as a request to stop cleanly: long loops poll the flag, return an error, and
//! their temporary output files are removed as they are dropped.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// What long loops poll: set by Ctrl-C, or by [`stop_the_others`].
static FLAG: AtomicBool = AtomicBool::new(false);
/// Set by Ctrl-C only: whether the user asked (exit status 130, "again" means abort).
static USER: AtomicBool = AtomicBool::new(false);
static INSTALLED: OnceLock<()> = OnceLock::new();
static FIRST: OnceLock<Instant> = OnceLock::new();

/// Signals this close after the first are the same request: `timeout` (without
/// `--foreground`) and some schedulers signal both the process and its group, so one
/// request arrives twice within milliseconds. Taken for "Ctrl-C again", it aborted 4 of 6
/// `timeout` runs on lavapipe without writing the finished passes. A person pressing twice
/// takes longer than this.
const SAME_REQUEST: Duration = Duration::from_millis(300);

/// Installs the handler (once) and returns the flag to poll.
pub fn flag() -> &'static AtomicBool {
    INSTALLED.get_or_init(|| {
        let _ = ctrlc::set_handler(|| {
            let first = *FIRST.get_or_init(Instant::now);
            FLAG.store(true, Ordering::SeqCst);
            if USER.swap(true, Ordering::SeqCst) {
                if first.elapsed() < SAME_REQUEST {
                    return;
                }
                // Ctrl-C again: the user means it. `exit` runs no destructors, so the
                // temporaries being written are removed here.
                scatter_sim::output::remove_live_temporaries();
                std::process::exit(130);
            }
            // Ctrl-C in a shell also ends the readers of a pipe the output goes to: from
            // now on a write there fails (dropped, main.rs) rather than ending the process
            // before its clean stop.
            #[cfg(unix)]
            // SAFETY: changes one signal's disposition; ctrlc runs this handler on its own
            // thread, not in signal context.
            unsafe {
                libc::signal(libc::SIGPIPE, libc::SIG_IGN);
            }
            // The handler also takes SIGTERM and SIGHUP (ctrlc's `termination` feature) and
            // cannot tell them from Ctrl-C, so the message names both.
            eprintln!(
                "\ninterrupt: stopping at the next safe point (a second Ctrl-C or signal aborts)"
            );
        });
    });
    &FLAG
}

/// Whether the user asked to stop (Ctrl-C, or a closed output pipe: [`stop_on_closed_pipe`]),
/// as opposed to [`stop_the_others`].
pub fn requested() -> bool {
    USER.load(Ordering::SeqCst) || PIPE.load(Ordering::SeqCst)
}

/// Set when a write found the pipe it went to closed.
static PIPE: AtomicBool = AtomicBool::new(false);

/// A closed pipe on stdout or stderr becomes a request to stop, as Ctrl-C is: quitting
/// `less` in `stcvae generate … 2>&1 | less`, or a `tee` that died, ended the process with
/// SIGPIPE's default at the next progress line, leaving GBs of hidden temporaries and a
/// training's last up to 5,000 steps unsaved. The write itself then fails and its text is
/// dropped (main.rs's print macros). For commands whose product is a file; the tables of
/// `bench` keep the default (`stcvae bench render | head -1` ends quietly).
pub fn stop_on_closed_pipe() {
    #[cfg(unix)]
    {
        extern "C" fn on_sigpipe(_: libc::c_int) {
            // Atomic stores only: async-signal-safe.
            // Not USER: a Ctrl-C after it is then still a first one (USER taken as set
            // made the first press a repeat within SAME_REQUEST, which did nothing).
            PIPE.store(true, Ordering::SeqCst);
            FLAG.store(true, Ordering::SeqCst);
        }
        let handler: extern "C" fn(libc::c_int) = on_sigpipe;
        // SAFETY: called from main before the command starts any thread; the handler only
        // stores to atomics.
        unsafe {
            libc::signal(libc::SIGPIPE, handler as libc::sighandler_t);
        }
    }
}

/// Whether a write found its pipe closed ([`stop_on_closed_pipe`]).
pub fn pipe_closed() -> bool {
    PIPE.load(Ordering::SeqCst)
}

/// Stops the loops polling [`flag`] as Ctrl-C does, without it counting as the user's
/// request: one training thread's failure ends the others with their checkpoints, yet the
/// command exits with 1, not 130, and the user's first Ctrl-C is still a first.
pub fn stop_the_others() {
    FLAG.store(true, Ordering::SeqCst);
}
