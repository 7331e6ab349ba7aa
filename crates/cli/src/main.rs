//! `stcvae`: learned multiple scattering for fast subsurface-scattering rendering.

// std's print macros panic when the write fails. After Ctrl-C the terminal's pipe may be
// gone (`stcvae … 2>&1 | tee log`: the signal ends `tee` too), and a panic, or SIGPIPE's
// default of ending the process, then cut the clean stop short: a 1.5 GB hidden
// temporary left, a training checkpoint unsaved. These shadow them in every module below
// (declared after them) and drop the text where it cannot be written; the interrupt
// handler then ignores SIGPIPE (interrupt.rs). Before an interrupt, SIGPIPE still ends
// the process quietly in `bench` (`stcvae bench … | head -1`, [`default_sigpipe`]); the
// other commands take a closed pipe as a request to stop (interrupt::stop_on_closed_pipe).
// Other errors on standard output (a full disk) are kept, and the command then fails
// (stdout_check.rs).
macro_rules! eprintln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($arg)*);
    }};
}
macro_rules! println {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = writeln!(std::io::stdout(), $($arg)*) {
            crate::stdout_check::failed(&e);
        }
    }};
}
macro_rules! print {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = write!(std::io::stdout(), $($arg)*) {
            crate::stdout_check::failed(&e);
        }
    }};
}

mod bench;
mod bench_decoders;
mod bench_devices;
mod bench_error;
mod bench_render;
mod device;
mod experiment;
mod generate;
mod interrupt;
mod left_over;
mod merge;
mod model_cmds;
mod paths;
mod plots;
mod progress;
mod pt_cache;
mod render;
mod shipped;
mod stdout_check;
mod train;
mod whole;

/// The help text of argument `id` of `cmd` (empty if it has none), for tests that hold
/// help texts to the constants they quote.
#[cfg(test)]
fn help_of(cmd: &clap::Command, id: &str) -> String {
    cmd.get_arguments()
        .find(|a| a.get_id() == id)
        .and_then(|a| a.get_help())
        .map(|h| h.to_string())
        .unwrap_or_default()
}

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "stcvae",
    version,
    about = "Learned multiple scattering (ST-CVAE) for fast subsurface-scattering rendering",
    long_about = "Learned multiple scattering (ST-CVAE) for fast subsurface-scattering rendering.\n\n\
        Simulates random walks in a sphere of homogeneous medium (the ground truth and the \
        training data), trains conditional VAEs on them and uses them to jump over thousands \
        of scattering events at once when rendering translucent objects."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate random walks in the unit sphere and write a dataset (.bin) or a CSV (.csv).
    Generate(generate::Args),
    /// Train LengthGen, PathGen and EventGen and export the model file.
    Train(train::Args),
    /// Draw walks from a trained model at fixed conditions (CSV like `generate`).
    Sample(model_cmds::SampleArgs),
    /// Measure a model's distributions against fresh simulator walks (KS, Wasserstein).
    Eval(model_cmds::EvalArgs),
    /// Render a scene with volumetric path tracing or ST-CVAE (EXR + PNG + JSON).
    Render(render::Args),
    /// Concatenate dataset shards (.bin or .csv), or average renders (.exr) of one scene.
    Merge(merge::Args),
    /// Run an experiment that reproduces a result of the paper (configs/experiments/).
    Experiment(experiment::Args),
    /// Measure stcvae: the speed of its parts, its devices, and its error against other renderers.
    Bench(bench::Args),
}

/// Fails at once, naming `flag` and the part of `path` at fault, when the output could not
/// be written after the work (scatter_sim::output::check_output_path).
pub(crate) fn check_out(flag: &str, path: &std::path::Path) -> anyhow::Result<()> {
    paths::check_not_stdout(flag, path)?;
    scatter_sim::output::check_output_path(path)
        .map_err(|e| anyhow::anyhow!("{flag} {}: {e}", path.display()))
}

/// As [`check_out`] for a directory that the work will create files in (`label` names the
/// flag or config field): a file in the way or an unwritable ancestor fails at once.
pub(crate) fn check_out_dir(label: &str, dir: &std::path::Path) -> anyhow::Result<()> {
    scatter_sim::output::check_output_folder(dir)
        .map_err(|e| anyhow::anyhow!("{label} {}: {e}", dir.display()))
}

/// The command line, with negative numbers taken as values in every command (`--spp -1`
/// then meets the option's range error, not "unexpected argument '-1'").
fn parse_cli() -> Cli {
    fn negatives(c: clap::Command) -> clap::Command {
        c.allow_negative_numbers(true).mut_subcommands(negatives)
    }
    negatives(Cli::command())
        .try_get_matches()
        .and_then(|m| Cli::from_arg_matches(&m))
        .unwrap_or_else(|e| exit_on_usage(e.format(&mut negatives(Cli::command()))))
}

/// Help and version go out as clap writes them; a usage error becomes one line, as every
/// other error here (clap's own spans three to five: the error, a list of the arguments it
/// concerns, a tip, the usage, a pointer to --help), with clap's exit status 2.
fn exit_on_usage(e: clap::Error) -> ! {
    use clap::error::ErrorKind;
    if matches!(
        e.kind(),
        ErrorKind::DisplayHelp
            | ErrorKind::DisplayVersion
            | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
    ) {
        if e.use_stderr() {
            // Help for a command line without a subcommand goes to standard error, as
            // clap writes it, with its status 2.
            e.exit()
        }
        // Written as clap writes it, but a failed write is an error, as for every other
        // text on standard output (`--help > /dev/full` exited 0).
        if let Err(e) = e.print() {
            stdout_check::failed(&e);
        }
        if let Err(e) = stdout_check::check() {
            eprintln!("error: {e}");
            std::process::exit(1)
        }
        std::process::exit(e.exit_code())
    }
    // clap's "a value is required for '--out <OUT>' but none was supplied" for `--out ""`,
    // where a value was supplied: said as the scene argument's parser says it. (Only its
    // path parsers refuse "" this way; a list of choices keeps clap's words and the list,
    // and so does a flag given no value at all, which clap words alike.)
    use clap::error::{ContextKind, ContextValue};
    if e.kind() == ErrorKind::InvalidValue
        && matches!(e.get(ContextKind::InvalidValue), Some(ContextValue::String(v)) if v.is_empty())
        && !matches!(e.get(ContextKind::ValidValue), Some(ContextValue::Strings(v)) if !v.is_empty())
        && let Some(ContextValue::String(arg)) = e.get(ContextKind::InvalidArg)
        && given_empty(arg)
    {
        eprintln!("error: invalid value '' for '{arg}': an empty path names no file");
        std::process::exit(2)
    }
    eprintln!("{}", one_line(&e.render().to_string()));
    std::process::exit(2)
}

/// Whether the command line gives the flag of clap's `arg` (`--out <OUT>`) an empty value,
/// as `--out ""` or `--out=`.
fn given_empty(arg: &str) -> bool {
    let Some(flag) = arg
        .split_whitespace()
        .next()
        .filter(|f| f.starts_with("--"))
    else {
        return false;
    };
    let args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    let joined = format!("{flag}=");
    args.windows(2).any(|w| w[0] == *flag && w[1].is_empty()) || args.iter().any(|a| *a == *joined)
}

/// clap's error text up to its usage lines, joined into one line (a tip in brackets).
fn one_line(text: &str) -> String {
    text.lines()
        .map(str::trim)
        .take_while(|l| !l.starts_with("Usage:") && !l.starts_with("For more information"))
        .filter(|l| !l.is_empty())
        .map(|l| match l.strip_prefix("tip: ") {
            Some(tip) => format!("(tip: {tip})"),
            None => l.to_owned(),
        })
        .collect::<Vec<_>>()
        .join(" ")
}

fn main() {
    quiet_wayland_probe();
    default_sigpipe();
    let cli = parse_cli();
    note_unread_thread_count();
    if !matches!(cli.command, Command::Bench(_)) {
        interrupt::stop_on_closed_pipe();
    }
    let result = match cli.command {
        Command::Generate(a) => generate::run(a),
        Command::Train(a) => train::run(a),
        Command::Sample(a) => model_cmds::sample(a),
        Command::Eval(a) => model_cmds::evaluate(a),
        Command::Render(a) => render::run(a),
        Command::Merge(a) => merge::run(a),
        Command::Experiment(a) => experiment::run(a),
        Command::Bench(a) => bench::run(a),
    }
    .and_then(|()| stdout_check::check());
    if let Err(e) = result {
        // One line, whatever names or tags from the inputs it quotes.
        let e = scatter_sim::ranges::printable(&format!("{e:#}"));
        if interrupt::pipe_closed() {
            // 141 = 128 + SIGPIPE, what a shell reports for a process the signal ended.
            eprintln!("error: {e} (stopped: the pipe the output went to was closed)");
            std::process::exit(141);
        }
        eprintln!("error: {e}");
        std::process::exit(if interrupt::requested() {
            interrupt::exit_status()
        } else {
            1
        });
    }
}

/// On a machine with no graphical session (a server, CI) the Vulkan driver's window-system
/// code asks libwayland for a display while wgpu lists adapters, and libwayland prints
/// "error: XDG_RUNTIME_DIR is invalid or not set in the environment." twice — on every
/// `--device gpu|auto` run, even one that then renders on the CPU — though nothing here
/// needs a display. With neither variable set there is no Wayland session to find, and
/// pointing XDG_RUNTIME_DIR at the temp directory lets the same failed lookup stay silent.
fn quiet_wayland_probe() {
    let unset = |name| std::env::var_os(name).is_none_or(|v| v.is_empty());
    if unset("XDG_RUNTIME_DIR") && unset("WAYLAND_DISPLAY") {
        // (temp_dir() is TMPDIR as given: an empty or relative one brought the lines back.)
        let tmp = Some(std::env::temp_dir())
            .filter(|d| d.is_absolute())
            .unwrap_or_else(|| "/tmp".into());
        // SAFETY: the first statement of `main`, before any other thread exists.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", tmp) };
    }
}

/// rayon takes a RAYON_NUM_THREADS it cannot read (`abc`, `-1`) as unset, and every core
/// was used without a word: said once, since the outputs report the count as if chosen.
fn note_unread_thread_count() {
    if let Some(v) = std::env::var_os("RAYON_NUM_THREADS")
        && !v.is_empty()
        && v.to_str().is_none_or(|s| s.parse::<usize>().is_err())
    {
        eprintln!(
            "warning: RAYON_NUM_THREADS={} is not a whole number (0 or more), so it is \
             ignored: all cores are used where --threads does not say otherwise",
            scatter_sim::ranges::printable(&v.to_string_lossy())
        );
    }
}

/// Rust ignores SIGPIPE, so `stcvae bench render | head -1` made `println!` panic ("failed
/// printing to stdout: Broken pipe", exit 101) once `head` had closed the pipe. With the
/// default disposition the process ends quietly, as command-line tools do.
fn default_sigpipe() {
    #[cfg(unix)]
    // SAFETY: called first thing in main, before any thread exists; restoring a signal's
    // default disposition has no other effect on this program.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
