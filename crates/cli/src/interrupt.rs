//! Ctrl-C (or SIGTERM, SIGHUP, a closed output pipe) as a request to stop cleanly: long
//! loops poll the flag and end early (a render writes the passes it finished, other
//! commands return an error), and their temporary output files are removed as they are
//! dropped.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use std::time::{Duration, Instant};

/// What long loops poll: set by a stop signal, a closed output pipe, or
/// [`stop_the_others`].
static FLAG: AtomicBool = AtomicBool::new(false);
/// Set by Ctrl-C (or SIGTERM, SIGHUP) only: whether the user asked (exit status 128 + the
/// signal, "again" means abort).
static USER: AtomicBool = AtomicBool::new(false);
/// The first stop signal's number (0: none seen, or a platform where it is not known),
/// for the exit status: 128 + its number, as a shell reports for a process the signal
/// ended (130 for Ctrl-C, 143 for SIGTERM from `kill` or a batch scheduler, 129 for
/// SIGHUP), so that a script can tell who stopped it.
static SIGNAL: AtomicI32 = AtomicI32::new(0);
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
        #[cfg(unix)]
        let hangup_ignored = hangup_ignored();
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
                std::process::exit(exit_status());
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
            // The handler also takes SIGTERM and SIGHUP (ctrlc's `termination` feature).
            eprintln!(
                "\ninterrupt{}: stopping at the next safe point (a second Ctrl-C or signal \
                 aborts)",
                signal_name().map_or(String::new(), |n| format!(" ({n})"))
            );
        });
        #[cfg(unix)]
        {
            if hangup_ignored {
                // SAFETY: sets one signal's disposition to SIG_IGN.
                unsafe {
                    libc::signal(libc::SIGHUP, libc::SIG_IGN);
                }
            }
            record_signals();
        }
    });
    &FLAG
}

/// Whether the process was started with SIGHUP ignored, as `nohup` starts it: ctrlc
/// installs its handler over an ignored signal too, so `nohup stcvae train … &` stopped
/// when its terminal closed. It is put back to ignored. (A SIGINT ignored by a
/// non-interactive shell's `&` is still taken: test harnesses and CI runners start
/// commands that way, and Ctrl-C or `kill -INT` is how a user means to stop one.)
#[cfg(unix)]
fn hangup_ignored() -> bool {
    // SAFETY: reads the signal's current action into a zeroed (valid) struct.
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        libc::sigaction(libc::SIGHUP, std::ptr::null(), &mut old) == 0
            && old.sa_sigaction == libc::SIG_IGN
    }
}

/// The exit status of a command the user stopped: 128 + the first stop signal's number.
pub fn exit_status() -> i32 {
    match SIGNAL.load(Ordering::SeqCst) {
        0 => 130,
        n => 128 + n,
    }
}

fn signal_name() -> Option<&'static str> {
    #[cfg(unix)]
    match SIGNAL.load(Ordering::SeqCst) {
        libc::SIGINT => return Some("SIGINT"),
        libc::SIGTERM => return Some("SIGTERM"),
        libc::SIGHUP => return Some("SIGHUP"),
        _ => {}
    }
    None
}

/// The handlers ctrlc installed for the stop signals, called after ours records the
/// signal's number: ctrlc's handler runs one closure for all of them and cannot say which
/// came. Indexed as STOP_SIGNALS.
#[cfg(unix)]
static CHAINED: [std::sync::atomic::AtomicUsize; 3] =
    [const { std::sync::atomic::AtomicUsize::new(0) }; 3];

#[cfg(unix)]
const STOP_SIGNALS: [libc::c_int; 3] = [libc::SIGINT, libc::SIGTERM, libc::SIGHUP];

/// Puts a handler in front of ctrlc's for each stop signal that records the first one's
/// number, then calls ctrlc's. A signal whose current action is not a plain handler is
/// left alone: one ignored (SIGHUP under nohup) stays ignored, one at its default (ctrlc
/// failed to install) ends the process, and one caught by another library's `SA_SIGINFO`
/// handler exits 130 if that handler stops the command.
#[cfg(unix)]
fn record_signals() {
    extern "C" fn record(sig: libc::c_int) {
        // Atomic operations and a call to ctrlc's handler (a `sem_post`) only:
        // async-signal-safe.
        let _ = SIGNAL.compare_exchange(0, sig, Ordering::SeqCst, Ordering::SeqCst);
        if let Some(i) = STOP_SIGNALS.iter().position(|&s| s == sig) {
            let h = CHAINED[i].load(Ordering::SeqCst);
            if h != 0 {
                // SAFETY: `h` was read from sigaction as a plain handler of this type
                // (neither SIG_DFL, SIG_IGN nor an SA_SIGINFO handler) and stays installed
                // code for the life of the process.
                let f: extern "C" fn(libc::c_int) = unsafe { std::mem::transmute(h) };
                f(sig);
            }
        }
    }
    let handler: extern "C" fn(libc::c_int) = record;
    for (i, &sig) in STOP_SIGNALS.iter().enumerate() {
        // SAFETY: sigaction reads and writes the structs passed, which are zeroed (a valid
        // sigaction) and live across the calls; called once, from the thread that
        // installed ctrlc's handlers, before any stop can be handled by ours.
        unsafe {
            let mut old: libc::sigaction = std::mem::zeroed();
            if libc::sigaction(sig, std::ptr::null(), &mut old) != 0
                || old.sa_flags & libc::SA_SIGINFO != 0
                || old.sa_sigaction == libc::SIG_DFL
                || old.sa_sigaction == libc::SIG_IGN
            {
                continue;
            }
            CHAINED[i].store(old.sa_sigaction, Ordering::SeqCst);
            let mut new = old;
            new.sa_sigaction = handler as libc::sighandler_t;
            libc::sigaction(sig, &new, std::ptr::null_mut());
        }
    }
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
/// command exits with 1, not 128 + a signal, and the user's first Ctrl-C is still a first.
pub fn stop_the_others() {
    FLAG.store(true, Ordering::SeqCst);
}
