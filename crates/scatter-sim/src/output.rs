//! Output files that appear whole or not at all.
//!
//! Everything stcvae writes goes to a temporary file beside the target and is renamed over
//! it only once complete, so an error, a Ctrl-C or a crash never leaves a half-written
//! file under the output name (the temporary is removed when dropped).

use std::collections::HashMap;
use std::fs;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use tempfile::NamedTempFile;

/// Checks, before long work starts, that [`AtomicFile::create`] will be able to write `path`:
/// the nearest existing ancestor of its directory is a directory in which files can be
/// created (probed with a temporary file, removed at once) and renamed (its flags), and
/// `path` is a file the final rename can replace ([`check_replaceable`]; nor another user's
/// file in a sticky folder, nor an immutable one). Otherwise the message says which part of the path
/// is at fault, e.g. "x exists and is not a directory" instead of the "File exists" that
/// creating the directories would report after the work.
pub fn check_output_path(path: &Path) -> Result<(), String> {
    check_replaceable(path).map_err(|e| after_path(path, &e))?;
    let text = path.as_os_str().to_string_lossy();
    if text.ends_with('/') || text.ends_with(std::path::MAIN_SEPARATOR) {
        return Err(format!("{text} ends with a path separator: name a file"));
    }
    let Some(probe) = probe_folder(folder_of(path))? else {
        return Ok(());
    };
    #[cfg(unix)]
    check_renamable(path, probe.as_file())?;
    drop(probe);
    Ok(())
}

/// As [`check_output_path`] for a folder that the work will write files into (a
/// checkpoint folder, `bench render --save`): the folder's own checks, with no file in it
/// to judge (a name made up inside it was judged as a target: another user's file of that
/// name in a sticky folder refused the folder).
pub fn check_output_folder(dir: &Path) -> Result<(), String> {
    check_place(dir, dir).map_err(|e| after_path(dir, &e))?;
    probe_folder(dir).map(drop)
}

/// An error about `path`: the checks' own refusals read on from the path ("x is a
/// directory"); an error of the system follows a colon.
fn after_path(path: &Path, e: &io::Error) -> String {
    let sep = if e.raw_os_error().is_some() { ":" } else { "" };
    format!("{}{sep} {e}", path.display())
}

/// The nearest existing ancestor of `dir` (itself included), checked to be a folder in
/// which files can be made (the probe file, made there and returned), and, on Linux, one
/// whose flags let them be renamed (None: nothing on the path exists, or the probe could
/// not be removed from it again).
fn probe_folder(dir: &Path) -> Result<Option<NamedTempFile>, String> {
    // The nearest ancestor that is there at all: a symbolic link counts even when it
    // points nowhere (exists() would step over it, and creating the directories would
    // then fail after the work).
    // (A relative path's last ancestor is the empty path: the working directory.)
    let Some(existing) = dir
        .ancestors()
        .map(|a| {
            if a.as_os_str().is_empty() {
                Path::new(".")
            } else {
                a
            }
        })
        .find(|a| fs::symlink_metadata(a).is_ok())
    else {
        return Ok(None);
    };
    if !existing.exists() {
        return Err(format!(
            "{} is a symbolic link to nothing",
            existing.display()
        ));
    }
    if !existing.is_dir() {
        return Err(format!(
            "{} exists and is not a directory",
            existing.display()
        ));
    }
    // Files can be made in an append-only folder, but neither renamed nor removed: an
    // output there failed after the work, and the probe and the temporary stayed. Folders
    // can be made in it, though, and an output in one of them is written as anywhere: the
    // probe is then skipped, since it could not be removed.
    #[cfg(target_os = "linux")]
    match fixed_flags(existing, true) {
        0 => {}
        f if f & IMMUTABLE == 0 && existing != dir => return Ok(None),
        _ => {
            return Err(format!(
                "{} is immutable or append-only (chattr +i or +a): no output can be renamed \
                 into it",
                existing.display()
            ));
        }
    }
    tempfile::Builder::new()
        .prefix(".stcvae-write-check.")
        .tempfile_in(existing)
        .map(Some)
        .map_err(|e| {
            format!(
                "cannot create files in {}: {}",
                existing.display(),
                e.kind()
            )
        })
}

/// Refuses a target that the rename at the end of the work could not replace, though
/// files can be made beside it: another user's file in a folder with the sticky bit (as
/// /tmp has), and an immutable or append-only file (`chattr +i`, `+a`). Each failed with
/// "Operation not permitted" only once a render or a dataset was done. `probe`, a file
/// just made in the folder, is owned by whoever this process writes as.
#[cfg(unix)]
fn check_renamable(path: &Path, probe: &fs::File) -> Result<(), String> {
    use std::os::unix::fs::MetadataExt;
    let (Ok(target), Ok(folder), Ok(me)) = (
        fs::symlink_metadata(path),
        fs::metadata(folder_of(path)),
        probe.metadata(),
    ) else {
        return Ok(());
    };
    if sticky_keeps(me.uid(), folder.mode(), folder.uid(), target.uid()) {
        return Err(format!(
            "{} is another user's file in a folder with the sticky bit (as /tmp has), which \
             only its owner may replace: choose another name",
            path.display()
        ));
    }
    #[cfg(target_os = "linux")]
    if target.is_file() && fixed_flags(path, false) != 0 {
        return Err(format!(
            "{} is immutable or append-only (chattr +i or +a), so no output can replace it: \
             choose another name",
            path.display()
        ));
    }
    Ok(())
}

/// Whether a folder's sticky bit keeps a user (`me`) from replacing a file in it: only the
/// file's owner, the folder's and root may (root's override, CAP_FOWNER, is assumed).
#[cfg(unix)]
fn sticky_keeps(me: u32, folder_mode: u32, folder_owner: u32, file_owner: u32) -> bool {
    folder_mode & 0o1000 != 0 && me != 0 && me != file_owner && me != folder_owner
}

/// linux/fs.h's FS_IMMUTABLE_FL and FS_APPEND_FL: nothing in such a file or folder may be
/// renamed over or out of, by root either; an append-only folder still takes new files and
/// folders.
#[cfg(target_os = "linux")]
const IMMUTABLE: libc::c_int = 0x10;
#[cfg(target_os = "linux")]
const APPEND_ONLY: libc::c_int = 0x20;

/// The immutable and append-only flags of the file or folder at `path` (0 for one this user
/// cannot open to read), through a symbolic link where `follow` (a folder reached through a
/// link is the folder written into; a target that is a link is replaced itself).
#[cfg(target_os = "linux")]
fn fixed_flags(path: &Path, follow: bool) -> libc::c_int {
    use std::os::fd::AsRawFd;
    use std::os::unix::fs::OpenOptionsExt;
    let nofollow = if follow { 0 } else { libc::O_NOFOLLOW };
    let Ok(f) = fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | nofollow)
        .open(path)
    else {
        return 0;
    };
    // The ioctl's number says long, but the kernel writes an int (a long read back would
    // hold the flags in its high half on a big-endian machine).
    let mut flags: libc::c_int = 0;
    // SAFETY: FS_IOC_GETFLAGS writes one int into `flags`, which lives past the call.
    let ok = unsafe { libc::ioctl(f.as_raw_fd(), libc::FS_IOC_GETFLAGS, &mut flags) } == 0;
    if ok {
        flags & (IMMUTABLE | APPEND_ONLY)
    } else {
        0
    }
}

/// Refuses an output `path` that must not be replaced: an output is a finished file
/// renamed over whatever is there, which would destroy a FIFO or a device node
/// (`/dev/null` written as root), and cannot replace a directory. Nor is anything written
/// into /dev, /proc or /sys (`system_folder`): `--out /dev/stdout` as root replaced
/// that link with a file, for every process of the machine. A symbolic link is
/// replaced like a file (its target is left as it is): following it would let another
/// user's link in a shared folder such as /tmp aim an output at the writer's own files.
/// The error's message follows the path, e.g. "x is a directory".
pub fn check_replaceable(path: &Path) -> io::Result<()> {
    check_place(folder_of(path), path)?;
    let meta = match fs::symlink_metadata(path) {
        // Not there (or a file on the way, which the caller's directory checks name).
        Err(e)
            if matches!(
                e.kind(),
                io::ErrorKind::NotFound | io::ErrorKind::NotADirectory
            ) =>
        {
            return Ok(());
        }
        Err(e) => return Err(e),
        Ok(m) => m,
    };
    let kind = meta.file_type();
    if kind.is_dir() {
        return Err(io::Error::new(
            io::ErrorKind::IsADirectory,
            "is a directory",
        ));
    }
    if !(kind.is_file() || kind.is_symlink()) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "exists and is not a regular file (a FIFO, device or socket): outputs are written \
             to a new file renamed over the old, so name a regular file or a new path",
        ));
    }
    Ok(())
}

/// Refuses a place no output may be written: `path` going up (`..`) out of a folder that
/// does not exist yet ([`missing_before_parent`]), and `dir` (the output's folder, or the
/// folder itself) in /dev, /proc or /sys ([`system_folder`]).
fn check_place(dir: &Path, path: &Path) -> io::Result<()> {
    if let Some(missing) = missing_before_parent(path) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "goes up (`..`) out of {}, which does not exist yet: write the path without \
                 it",
                missing.display()
            ),
        ));
    }
    if let Some(real) = system_folder(dir) {
        let shown = dir.display().to_string();
        let real = real.display().to_string();
        let real = if real == shown {
            String::new()
        } else {
            format!(", that is {real}")
        };
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "is in {shown}{real}, a folder of devices and kernel entries: stcvae writes \
                 files, renamed over what is there, not to standard output or devices; name \
                 a file elsewhere"
            ),
        ));
    }
    Ok(())
}

/// The first component of `path` that does not exist, where a `..` comes after it. Such a
/// path escaped every check of what it names: `new/../a.exr` is resolved through `.`, its
/// nearest existing ancestor, as `./new/../a.exr`, a file that is not there, while the
/// write made `new` and renamed the output over `a.exr`, an input of the same command
/// (and `new/../../dev/x` reached /dev). Refused rather than resolved by hand: the folder
/// made for nothing would stay.
fn missing_before_parent(path: &Path) -> Option<PathBuf> {
    use std::path::Component;
    let mut at = PathBuf::new();
    let mut missing = None;
    for c in path.components() {
        if c == Component::ParentDir && missing.is_some() {
            return missing;
        }
        at.push(c);
        // Only what is not there: a file on the way (NotADirectory) is named by the
        // folder checks as what it is.
        if missing.is_none()
            && matches!(c, Component::Normal(_))
            && fs::symlink_metadata(&at).is_err_and(|e| e.kind() == io::ErrorKind::NotFound)
        {
            missing = Some(at.clone());
        }
    }
    None
}

/// `dir` resolved, where it is /dev itself or lies under /proc or /sys (Linux's device
/// and kernel folders): `--out /dev/stdout` reaches /dev, `/dev/fd/1` /proc, and
/// `/dev/new/x` would make a folder in /dev. Folders below /dev that are there, such as
/// the tmpfs /dev/shm, hold files and are let through. A folder not made yet resolves
/// through its nearest existing ancestor.
fn system_folder(dir: &Path) -> Option<PathBuf> {
    let existing = dir.ancestors().find(|a| a.exists())?;
    let made = dir.strip_prefix(existing).ok()?;
    let real = fs::canonicalize(existing).ok()?;
    let system =
        (real == Path::new("/dev")) || real.starts_with("/proc") || real.starts_with("/sys");
    // (join("") would add a separator: "/dev/".)
    system.then(|| {
        if made.as_os_str().is_empty() {
            real
        } else {
            real.join(made)
        }
    })
}

/// The temporaries being written now, so that an abort that skips destructors (a second
/// Ctrl-C calls `exit`) can still remove them: each is registered while its guard lives.
static LIVE: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

/// Keeps a temporary's path (a file, or a folder of them) in `LIVE` until dropped
/// (after its rename or removal).
pub struct Live(PathBuf);

impl Live {
    pub fn new(path: &Path) -> Self {
        LIVE.lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(path.to_path_buf());
        Self(path.to_path_buf())
    }
}

impl Drop for Live {
    fn drop(&mut self) {
        let mut live = LIVE.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = live.iter().position(|p| *p == self.0) {
            live.swap_remove(i);
        }
    }
}

/// Removes every temporary still being written: for an exit that skips destructors. The
/// caller is a signal handler's own thread (ctrlc runs it on an ordinary thread), and the
/// lock's holders only push or remove a path, so waiting for it is brief.
pub fn remove_live_temporaries() {
    let live = LIVE.lock().unwrap_or_else(|e| e.into_inner());
    for p in live.iter() {
        if p.is_dir() {
            let _ = fs::remove_dir_all(p);
        } else {
            let _ = fs::remove_file(p);
        }
    }
}

/// Removes the hidden temporaries an aborted write of `path` can leave beside it (its
/// `.NAME.XXXXXX.partial` files) and says so: a second Ctrl-C exits without destructors,
/// and a temporary made in the instant before its registration in `LIVE` is missed. For
/// outputs only one command writes at a time (a training's checkpoints), called before it
/// writes them again; the links a killed set left are [`restore_killed_sets`]'.
pub fn remove_stale_temporaries_of(path: &Path) {
    let dir = folder_of(path);
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    let prefix = temp_prefix(path);
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        // (`.previous`: the links of versions before the sets' marks, which no sweep of
        // today's reads.)
        let ours = [".partial", ".previous"]
            .iter()
            .any(|suffix| is_temporary_name(&name, &prefix, suffix));
        if !ours || !e.file_type().is_ok_and(|t| t.is_file()) {
            continue;
        }
        let bytes = e.metadata().map_or(0, |m| m.len());
        if fs::remove_file(e.path()).is_ok() {
            note(&format!(
                "note: removed {} ({bytes} bytes), the temporary of an earlier run that was \
                 stopped while writing {}",
                crate::ranges::printable_path(&e.path()),
                crate::ranges::printable_path(path)
            ));
        }
    }
}

/// Whether `name` is a temporary tempfile made with `prefix` and `suffix`: its six random
/// characters between the two (`x`'s prefix `.x.` also begins `x.json`'s temporaries).
fn is_temporary_name(name: &str, prefix: &str, suffix: &str) -> bool {
    name.len() == prefix.len() + 6 + suffix.len()
        && name.starts_with(prefix)
        && name.ends_with(suffix)
}

/// A note on stderr that cannot end the process: std's `eprintln!` panics where stderr is
/// a closed pipe (`stcvae … 2>&1 | less`, less quit), which the CLI takes as a request to
/// stop cleanly.
pub fn note(line: &str) {
    let _ = writeln!(io::stderr(), "{line}");
}

/// A new temporary in `dir`, locked: the lock is held while this process has the file open
/// (the OS drops it when the process dies) and marks the temporary as being written, for
/// [`remove_killed_temporaries`]. Between its creation and the lock another run's sweep
/// may take and remove it; a file that no longer has its name is then made again (the
/// write would have gone to an unlinked file and its rename failed after the work). The
/// lock waits for such a sweep to let go. Where the file system has no locks the
/// temporary is never swept.
// Only Unix can tell a swept temporary from its own (dev and inode), so only there does the
// loop go round again.
#[cfg_attr(not(unix), allow(clippy::never_loop))]
fn locked_temporary(builder: &tempfile::Builder, dir: &Path) -> io::Result<NamedTempFile> {
    for _ in 0..8 {
        let tmp = builder.tempfile_in(dir).map_err(without_temporary)?;
        if tmp.as_file().lock().is_err() {
            return Ok(tmp);
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            let open = tmp.as_file().metadata()?;
            let named = fs::symlink_metadata(tmp.path());
            if !named.is_ok_and(|n| n.dev() == open.dev() && n.ino() == open.ino()) {
                // Swept: its name is gone, and dropping `tmp` finds nothing to remove.
                continue;
            }
        }
        return Ok(tmp);
    }
    Err(io::Error::other(
        "its temporary file was removed as soon as it was made, eight times",
    ))
}

/// tempfile's error without the temporary's path it adds ("… at path
/// …/.x.exr.XXXXXX.partial"), a file that is gone by the time the message is read: the
/// callers name the output itself.
fn without_temporary(e: io::Error) -> io::Error {
    match e.get_ref().and_then(|inner| inner.source()) {
        Some(cause) => io::Error::new(e.kind(), cause.to_string()),
        None => e,
    }
}

/// Removes the `.NAME.XXXXXX.partial` temporaries beside `path` (`prefix` is
/// [`temp_prefix`]'s) that no process is writing, and returns them with their sizes. Each
/// writer holds a lock on its temporary ([`AtomicFile::create`]), which the OS releases
/// when the process dies, so one whose lock can be taken was left by a run that was
/// killed (SIGKILL, the OOM killer, a power cut) before any handler could remove it: a
/// killed `generate` left a hidden `.y.csv.XXXXXX.partial` that no later run removed or
/// named, and a dataset's holds hundreds of MB. A temporary another run is writing keeps
/// its lock and is left alone.
fn remove_killed_temporaries(path: &Path, prefix: &str) -> Vec<(PathBuf, u64)> {
    const FRESH_TEMPORARY: std::time::Duration = std::time::Duration::from_secs(3);
    let Ok(entries) = fs::read_dir(folder_of(path)) else {
        return Vec::new();
    };
    let mut gone = Vec::new();
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let ours = is_temporary_name(&name, prefix, ".partial");
        if !ours || !e.file_type().is_ok_and(|t| t.is_file()) {
            continue;
        }
        let Ok(f) = fs::File::open(e.path()) else {
            continue;
        };
        // Younger than a few seconds: possibly another run's, made an instant before its
        // lock (`locked_temporary`); a killed run's is swept by a later write.
        let fresh = f
            .metadata()
            .and_then(|m| m.modified())
            .is_ok_and(|t| t.elapsed().is_ok_and(|age| age < FRESH_TEMPORARY));
        if !fresh && f.try_lock().is_ok() {
            let bytes = f.metadata().map_or(0, |m| m.len());
            if fs::remove_file(e.path()).is_ok() {
                gone.push((e.path(), bytes));
            }
        }
    }
    gone
}

/// Refuses an input path that is a named pipe, a socket or a device: opening a FIFO with
/// no writer blocks for ever (a scene, mesh, model or image given as one hung the command,
/// deaf to a first Ctrl-C), and stcvae reads its inputs whole, with their size known.
/// Only the file's metadata is read, which does not block.
pub fn check_input(path: &Path) -> io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = fs::metadata(path)?.file_type();
        let what = if t.is_fifo() {
            Some("a named pipe (FIFO)")
        } else if t.is_socket() {
            Some("a socket")
        } else if t.is_char_device() || t.is_block_device() {
            Some("a device")
        } else {
            None
        };
        if let Some(what) = what {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("is {what}, not a file: give a regular file"),
            ));
        }
    }
    #[cfg(not(unix))]
    let _ = path;
    Ok(())
}

/// [`fs::read_to_string`] of an input, after [`check_input`].
pub fn read_input_to_string(path: &Path) -> io::Result<String> {
    check_input(path)?;
    fs::read_to_string(path)
}

/// The folder `path` lies in: its parent, or "." for a bare file name (whose parent is
/// the empty path).
fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// The start of a temporary's name beside `path` (".NAME."): at most 64 bytes standing for
/// the target's name, so that the temporary stays within a file system's 255-byte names
/// whenever the target's name does (the whole name plus ".XXXXXX.partial" failed for names
/// of 236–255 bytes, after the work was done).
fn temp_prefix(path: &Path) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    if name.len() <= 64 {
        return format!(".{name}.");
    }
    // Longer names: their first 55 bytes and a checksum of the whole name, so that two
    // outputs that differ only further on (long shard names) have prefixes of their own
    // and a sweep ([`remove_killed_temporaries`]) keeps to its own output's temporaries.
    let mut cut = 55;
    while !name.is_char_boundary(cut) {
        cut -= 1;
    }
    format!(
        ".{}~{:08x}.",
        &name[..cut],
        crc32fast::hash(name.as_bytes())
    )
}

/// A buffered writer to a temporary file that becomes `path` on [`AtomicFile::commit`].
pub struct AtomicFile {
    path: PathBuf,
    writer: BufWriter<Temporary>,
    live: Live,
    // Last: dropped after the temporary file, whose folder is then empty.
    made: MadeDirs,
}

/// The folders [`AtomicFile::create`] made for its target, deepest first: removed again
/// (each only while empty) when the file is dropped uncommitted, since an interrupted
/// `generate --out new/sub/x.bin` left `new/sub/` behind. A run aborted by a second Ctrl-C
/// still leaves them (its temporary files are removed, nothing else is).
struct MadeDirs(Vec<PathBuf>);

impl MadeDirs {
    /// Makes `dir` one level at a time and records the levels this call made: a level that
    /// another run made meanwhile is not this one's to remove. (A path through a missing
    /// level and back out, `x/../old`, is refused before: [`check_replaceable`].)
    fn create(dir: &Path) -> io::Result<Self> {
        let mut missing = Vec::new();
        let mut at = Some(dir);
        while let Some(d) = at {
            if d.as_os_str().is_empty() || d.exists() {
                break;
            }
            missing.push(d);
            at = d.parent();
        }
        let mut made = Self(Vec::new());
        for d in missing.into_iter().rev() {
            match fs::create_dir(d) {
                // Deepest first, as Drop removes them.
                Ok(()) => made.0.insert(0, d.to_path_buf()),
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists && d.is_dir() => {}
                // What was made so far is removed again (dropping `made`).
                Err(e) => return Err(e),
            }
        }
        Ok(made)
    }
}

impl Drop for MadeDirs {
    fn drop(&mut self) {
        for d in &self.0 {
            // Not empty (another program's file, a sibling output): kept, and its parents.
            if fs::remove_dir(d).is_err() {
                break;
            }
        }
    }
}

impl AtomicFile {
    /// Creates the temporary file in `path`'s directory (creating the directory); refuses a
    /// `path` that cannot be replaced ([`check_replaceable`]; callers name the path).
    pub fn create(path: &Path) -> io::Result<Self> {
        check_replaceable(path)?;
        let dir = folder_of(path);
        let made = MadeDirs::create(dir)?;
        let mut builder = tempfile::Builder::new();
        let prefix = temp_prefix(path);
        builder.prefix(&prefix).suffix(".partial");
        // An ordinary file's mode, which the umask then narrows like any other program's
        // (a fixed 0644 after writing made files readable under umask 077).
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            builder.permissions(std::fs::Permissions::from_mode(0o666));
        }
        for (gone, bytes) in remove_killed_temporaries(path, &prefix) {
            note(&format!(
                "note: removed {} ({bytes} bytes), the temporary of an earlier run that was \
                 killed while writing {}",
                crate::ranges::printable_path(&gone),
                crate::ranges::printable_path(path)
            ));
        }
        let tmp = locked_temporary(&builder, dir)?;
        Ok(Self {
            path: path.to_path_buf(),
            live: Live::new(tmp.path()),
            writer: BufWriter::with_capacity(1 << 20, Temporary(tmp)),
            made,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Flushes, syncs and renames the temporary over the target.
    pub fn commit(self) -> io::Result<()> {
        self.finish()?.persist()
    }

    /// Flushes and syncs the temporary: everything but the rename, which can then no
    /// longer fail for want of space.
    fn finish(self) -> io::Result<Finished> {
        let Temporary(tmp) = self.writer.into_inner().map_err(|e| e.into_error())?;
        tmp.as_file().sync_all()?;
        Ok(Finished {
            tmp,
            path: self.path,
            _live: self.live,
            made: self.made,
        })
    }
}

/// The temporary, written through its `File`: NamedTempFile's own `Write` adds "at path
/// …/.NAME.XXXXXX.partial" to every error, naming a file that is gone by the time the
/// message is read (the callers name the output itself).
struct Temporary(NamedTempFile);

impl Write for Temporary {
    #[inline]
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0.as_file_mut().write(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.0.as_file_mut().flush()
    }
}

/// A complete, synced temporary waiting to be renamed over its target.
struct Finished {
    tmp: NamedTempFile,
    path: PathBuf,
    _live: Live,
    // Last: the folders go only if the rename does not happen.
    made: MadeDirs,
}

impl Finished {
    fn persist(mut self) -> io::Result<()> {
        self.tmp.persist(&self.path).map_err(|e| e.error)?;
        // The folders hold the output now.
        self.made.0.clear();
        Ok(())
    }
}

impl Write for AtomicFile {
    #[inline]
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.writer.write(buf)
    }
    #[inline]
    fn write_all(&mut self, buf: &[u8]) -> io::Result<()> {
        self.writer.write_all(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.writer.flush()
    }
}

/// Writes `bytes` to `path` atomically.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut f = AtomicFile::create(path)?;
    f.write_all(bytes)?;
    f.commit()
}

/// Writes several files as one output: every temporary is written first and only then
/// are they renamed into place, so a failure while writing (a full disk, a path that is a
/// directory) leaves the previous set untouched instead of a new image beside an old
/// report. A rename that fails (a file another user owns in a sticky folder such as /tmp,
/// an immutable file) puts back the files of the set already renamed: their predecessors
/// are kept as hard links until the set is in place. The error names the file it concerns.
pub fn write_atomic_set(files: &[(&Path, &[u8])]) -> Result<(), (PathBuf, io::Error)> {
    write_atomic_set_streamed(bytes_of(files))
}

/// [`write_atomic_set`], then `then` while the set's folder is still locked against other
/// sets' renames (where it can be locked: `lock_folder`): what depends on the set just
/// placed and on no other run's set landing in between (a render without --variance
/// removing an OUT.var.exr that another render of the same output, with --variance, might
/// be placing at that moment).
pub fn write_atomic_set_then(
    files: &[(&Path, &[u8])],
    then: impl FnOnce(),
) -> Result<(), (PathBuf, io::Error)> {
    write_set_with(bytes_of(files), Finished::persist, Previous::keep, then)
}

/// What writes one file of a set into its temporary ([`write_atomic_set_streamed`]).
pub type Contents<'a> = Box<dyn FnOnce(&mut dyn Write) -> io::Result<()> + 'a>;

/// [`write_atomic_set`] for files written as they are made rather than held in memory
/// first (a pixel table of several GB beside its images).
pub fn write_atomic_set_streamed(
    files: Vec<(&Path, Contents<'_>)>,
) -> Result<(), (PathBuf, io::Error)> {
    write_set_with(files, Finished::persist, Previous::keep, || ())
}

/// Files held in memory, as a set's [`Contents`].
fn bytes_of<'a>(files: &[(&'a Path, &'a [u8])]) -> Vec<(&'a Path, Contents<'a>)> {
    files
        .iter()
        .map(|&(path, bytes)| {
            let write: Contents<'a> = Box::new(move |w: &mut dyn Write| w.write_all(bytes));
            (path, write)
        })
        .collect()
}

/// [`write_atomic_set_streamed`] with the rename and the keeping of predecessors given, so
/// that tests can make either fail, and what to do `then` ([`write_atomic_set_then`]).
fn write_set_with(
    files: Vec<(&Path, Contents<'_>)>,
    mut persist: impl FnMut(Finished) -> io::Result<()>,
    keep: impl Fn(&Path, &mut Marks) -> Before,
    then: impl FnOnce(),
) -> Result<(), (PathBuf, io::Error)> {
    let mut ready: Vec<Finished> = Vec::with_capacity(files.len());
    for (path, write) in files {
        // Written out and synced now, not at the rename: a full disk must fail here,
        // before any file of the set has replaced its predecessor.
        let written = AtomicFile::create(path).and_then(|mut f| {
            write(&mut f)?;
            f.finish()
        });
        match written {
            Ok(f) => ready.push(f),
            Err(e) => {
                // Newest first: a file's new folders may hold later files' temporaries,
                // never earlier ones' (first to last, new/ stayed when its second file's
                // temporary was still in it).
                ready.into_iter().rev().for_each(drop);
                return Err((path.to_path_buf(), e));
            }
        }
    }
    // Held until the set is in place (dropped on return).
    let _folder = ready.first().and_then(|f| lock_folder(folder_of(&f.path)));
    // A killed set's files in these folders are put back first, before this set replaces
    // them ([`restore_killed_sets`]).
    // (Each once: `dedup` alone kept a folder that came back after another.)
    let mut folders: Vec<&Path> = ready.iter().map(|f| folder_of(&f.path)).collect();
    folders.sort();
    folders.dedup();
    for dir in folders {
        restore_killed_sets(dir);
    }
    let mut marks = Marks::new();
    let mut placed: Vec<(PathBuf, Before)> = Vec::with_capacity(ready.len());
    // The folders the set made stay removable until every file is in place: a rename
    // that fails takes the set's earlier files back out, and then their new folders too.
    let mut made = Vec::with_capacity(ready.len());
    let mut ready = ready.into_iter();
    while let Some(mut f) = ready.next() {
        let path = f.path.clone();
        let before = keep(&path, &mut marks);
        #[cfg(unix)]
        if let (Before::Kept(_), Ok(m)) = (&before, f.tmp.as_file().metadata()) {
            use std::os::unix::fs::MetadataExt;
            marks.note_placing(&path, m.ino());
        }
        made.push(std::mem::replace(&mut f.made, MadeDirs(Vec::new())));
        if let Err(e) = persist(f) {
            // The temporaries not yet renamed go first, newest first with their folders as
            // above, so that the earlier files' folders can empty.
            ready.rev().for_each(drop);
            // Newest first, so each file gets back what it held before this call.
            let mut unrestored = false;
            for (done, before) in placed.into_iter().rev() {
                match before {
                    Before::Kept(p) => {
                        unrestored |= p.restore(&done).is_err();
                    }
                    Before::Absent => {
                        let _ = fs::remove_file(&done);
                    }
                    // Replaced for good: the new file stays rather than nothing.
                    Before::Unkept => {}
                }
            }
            if unrestored {
                // The link that could not be renamed back stays, and so does the mark, for
                // the next write into the folder to put it back.
                marks.abandon();
            } else {
                marks.finish();
            }
            // A folder made later is never the parent of one made earlier: newest first.
            made.into_iter().rev().for_each(drop);
            return Err((path, e));
        }
        placed.push((path, before));
    }
    // The set is in place: a kill from here on leaves it so (its links are then only
    // removed), and so must `then`'s work.
    marks.finish();
    drop(placed);
    for mut m in made {
        // The folders hold the output now.
        m.0.clear();
    }
    then();
    Ok(())
}

/// A set's mark's name ([`Marks`]): `.stcvae-set.ID.renaming`, made as `….marking`.
const MARK_PREFIX: &str = ".stcvae-set.";
const MARK_SUFFIX: &str = ".renaming";
const MARKING_SUFFIX: &str = ".marking";
/// A kept file's link is its temporaries' prefix, the set's id and this: a suffix of its
/// own, so that no other program's `.x.backup.previous` is taken for one.
const LINK_SUFFIX: &str = ".stcvae-previous";
/// The characters of a set's id.
const ID_LEN: usize = 6;

/// Whether `id` has the form of a set's id: six ASCII letters or digits, as tempfile makes.
fn is_set_id(id: &str) -> bool {
    id.len() == ID_LEN && id.bytes().all(|b| b.is_ascii_alphanumeric())
}

/// The mark `.stcvae-set.ID` + `suffix` in `dir`.
fn mark_path(dir: &Path, id: &str, suffix: &str) -> PathBuf {
    dir.join(format!("{MARK_PREFIX}{id}{suffix}"))
}

/// The id of a mark's name (`.stcvae-set.ID` + `suffix`).
fn mark_id<'a>(name: &'a str, suffix: &str) -> Option<&'a str> {
    let id = name.strip_prefix(MARK_PREFIX)?.strip_suffix(suffix)?;
    is_set_id(id).then_some(id)
}

/// A link's name split into its file's temporaries' prefix and its set's id.
fn link_of(name: &str) -> Option<(&str, &str)> {
    let rest = name.strip_suffix(LINK_SUFFIX)?;
    let cut = rest.len().checked_sub(ID_LEN)?;
    if !rest.is_char_boundary(cut) {
        return None;
    }
    let (prefix, id) = rest.split_at(cut);
    (prefix.len() > 1 && prefix.starts_with('.') && prefix.ends_with('.') && is_set_id(id))
        .then_some((prefix, id))
}

/// A folder's entries that are files or symbolic links, with their names as they are and
/// as text (to match against; a name that is not UTF-8 is joined back as it is).
fn files_in(dir: &Path) -> Vec<(std::ffi::OsString, String, fs::FileType)> {
    let Ok(entries) = fs::read_dir(dir) else {
        return Vec::new();
    };
    entries
        .flatten()
        .filter_map(|e| {
            let t = e.file_type().ok()?;
            (t.is_file() || t.is_symlink()).then(|| {
                let name = e.file_name();
                let text = name.to_string_lossy().into_owned();
                (name, text, t)
            })
        })
        .collect()
}

/// What a killed set left in `dir` is undone or cleared: a set keeps each file it replaces
/// as a link (`.NAME.ID.stcvae-previous`) until its renames are done, and marks the folder
/// (`.stcvae-set.ID.renaming`, locked from before it is visible) while they are under way,
/// noting in the mark each file it is about to place. A run killed (SIGKILL, the OOM
/// killer, a second Ctrl-C) left the links for ever, and its output a mix of the new set's
/// first files and the old set's others: a new EXR beside the old JSON, a new model beside
/// the old checkpoint JSON, whose checksum then refused the resume.
/// - A set whose mark is there and unlocked (its run is gone) was killed during its
///   renames: each link whose file is still the one the set placed is renamed back over
///   it. The earlier set's files are then as they were, but for a file the killed set
///   added (none before it), one it could not keep (no hard links there), and one
///   replaced since by another run (which stays).
/// - A link without a mark is of a set killed after its renames, while it removed its
///   links: the new set is whole, and the link is removed.
/// - A set whose mark is locked is being written now, and one whose mark cannot be read or
///   locked (another user's; a file system whose locks a read-only handle cannot take,
///   such as NFS) cannot be told from one: their links are left.
///
/// Unix only: elsewhere a file cannot be renamed over while another program has it open,
/// and the links are left.
pub fn restore_killed_sets(dir: &Path) {
    if !cfg!(unix) {
        return;
    }
    let first = files_in(dir);
    if !first
        .iter()
        .any(|(_, n, _)| link_of(n).is_some() || n.starts_with(MARK_PREFIX))
    {
        return;
    }
    // Half-made marks of killed runs (`….marking`, not yet linked to a mark's name) go; a
    // live run's is locked (one taken in the instant before its lock is made again, or,
    // in a set's later folder, the file there is not kept).
    for (name, text, t) in &first {
        if t.is_file() && mark_id(text, MARKING_SUFFIX).is_some() && Mark::dead(&dir.join(name)) {
            let _ = fs::remove_file(dir.join(name));
        }
    }
    // Which sets were killed, decided before their links are listed: a set found dead adds
    // no link after, where a listing made first could miss a link made since.
    let mut dead: HashMap<String, (fs::File, HashMap<String, u64>)> = HashMap::new();
    for (name, text, t) in &first {
        let Some(id) = mark_id(text, MARK_SUFFIX) else {
            continue;
        };
        if !t.is_file() {
            continue;
        }
        if let Some((lock, placed)) = Mark::read_dead(&dir.join(name)) {
            dead.insert(id.to_string(), (lock, placed));
        }
    }
    let now = files_in(dir);
    // Sets with a link that stayed (a rename refused): their marks stay too, or the next
    // sweep would take the link for a finished set's and remove it.
    let mut kept: std::collections::HashSet<String> = std::collections::HashSet::new();
    for (name, text, _) in &now {
        let Some((prefix, id)) = link_of(text) else {
            continue;
        };
        let link = dir.join(name);
        match dead.get(id) {
            Some((_, placed)) => {
                // The file it was kept for: the one whose temporaries take this prefix (a
                // long name's prefix holds a checksum of it, so the name cannot be read
                // back from it).
                let target = now.iter().find(|(_, n, _)| {
                    link_of(n).is_none() && temp_prefix(Path::new(n.as_str())) == prefix
                });
                let gone = match target {
                    Some((t, tn, _)) => put_back(&link, &dir.join(t), placed.get(tn).copied()),
                    // Its file was removed since: nothing to put back.
                    None => fs::remove_file(&link).is_ok(),
                };
                if !gone {
                    kept.insert(id.to_string());
                }
            }
            None => {
                // A set with no mark finished its renames. One whose mark is there but
                // not dead (live, or made after the marks were looked at) is left.
                let mark = mark_path(dir, id, MARK_SUFFIX);
                if fs::symlink_metadata(&mark).is_err() {
                    let _ = fs::remove_file(&link);
                }
            }
        }
    }
    // The killed sets' marks go once their links are dealt with (their locks held till
    // then), and so do those of killed sets that kept nothing.
    for (id, (lock, _)) in dead {
        if !kept.contains(&id) {
            let _ = fs::remove_file(mark_path(dir, &id, MARK_SUFFIX));
        }
        drop(lock);
    }
}

/// Renames a killed set's `link` back over `target`, the file it was kept for, and says
/// so, where `target` is still the file the set placed there (`placed`: its inode, as the
/// set noted it before the rename). A link to the file `target` still is (the set was
/// killed before that file's rename), or one whose file was replaced since by another run,
/// is only removed. Returns whether the link is gone: one that stays (a rename refused)
/// keeps its set's mark, for a later sweep.
fn put_back(link: &Path, target: &Path, placed: Option<u64>) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let id = |p: &Path| fs::symlink_metadata(p).map(|m| (m.dev(), m.ino())).ok();
        let (Some(l), Some(t)) = (id(link), id(target)) else {
            return false;
        };
        if l == t || placed != Some(t.1) {
            return fs::remove_file(link).is_ok();
        }
    }
    #[cfg(not(unix))]
    let _ = placed;
    let done = fs::rename(link, target).is_ok();
    if done {
        note(&format!(
            "note: put back the earlier {}: a run was killed part way through replacing it \
             and the files written with it",
            crate::ranges::printable_path(target)
        ));
    }
    done
}

/// A set's mark in each folder where it keeps a file it replaces, while its renames are
/// under way ([`restore_killed_sets`]): `.stcvae-set.ID.renaming`, locked from before it
/// can be seen (made as `….marking`, locked, then linked to its name) until its renames
/// are done or undone, when it is removed (the OS drops the lock when the process dies;
/// a rollback that could not put a file back leaves it, [`Marks::abandon`]).
/// Before each rename the set notes in it the inode it is about to place and the file's
/// name. Not in [`LIVE`]: a second Ctrl-C's exit leaves it, so that the next set written
/// there puts the killed one's files back.
struct Marks {
    /// Six characters naming the set in its marks and links.
    id: Option<String>,
    /// Each marked folder (as the set's paths name it), its mark and the mark's lock.
    held: Vec<(PathBuf, PathBuf, fs::File)>,
}

/// A set's mark as [`restore_killed_sets`] finds it.
struct Mark;

impl Mark {
    /// Whether the file at `path` can be locked: the run that made it is gone.
    fn dead(path: &Path) -> bool {
        fs::File::open(path).is_ok_and(|f| f.try_lock().is_ok())
    }

    /// The mark at `path`, if its run is gone: its lock (held by the caller until its
    /// links are dealt with) and the files the set noted, by name, with the inode it
    /// placed at each. None for a live mark, or one that cannot be opened or locked.
    fn read_dead(path: &Path) -> Option<(fs::File, HashMap<String, u64>)> {
        let mut f = fs::File::open(path).ok()?;
        f.try_lock().ok()?;
        let mut text = String::new();
        io::Read::read_to_string(&mut f, &mut text).ok()?;
        let placed = text
            .lines()
            .filter_map(|l| {
                let (ino, name) = l.split_once(' ')?;
                Some((name.to_string(), ino.parse().ok()?))
            })
            .collect();
        Some((f, placed))
    }
}

impl Marks {
    fn new() -> Self {
        Self {
            id: None,
            held: Vec::new(),
        }
    }

    /// The set's id, its folder `dir` marked (once); None where no mark can be made
    /// there, and the file it would keep is then not kept.
    fn in_folder(&mut self, dir: &Path) -> Option<String> {
        if let Some(id) = &self.id
            && self.held.iter().any(|(d, ..)| d == dir)
        {
            return Some(id.clone());
        }
        // A few tries: a sweep may take a half-made mark, or another set hold its id.
        for _ in 0..4 {
            let (marking, file, id) = match &self.id {
                Some(id) => {
                    let marking = mark_path(dir, id, MARKING_SUFFIX);
                    let file = mark_file().create_new(true).open(&marking).ok()?;
                    (marking, file, id.clone())
                }
                None => {
                    let mut b = tempfile::Builder::new();
                    b.prefix(MARK_PREFIX)
                        .suffix(MARKING_SUFFIX)
                        .rand_bytes(ID_LEN);
                    // Readable by others, whose sweeps could not open it otherwise and would
                    // leave its set's links for ever.
                    #[cfg(unix)]
                    {
                        use std::os::unix::fs::PermissionsExt;
                        b.permissions(fs::Permissions::from_mode(0o644));
                    }
                    let (file, marking) = b.tempfile_in(dir).ok()?.keep().ok()?;
                    let name = marking.file_name()?.to_string_lossy().into_owned();
                    let id = mark_id(&name, MARKING_SUFFIX)?.to_string();
                    (marking, file, id)
                }
            };
            let mark = mark_path(dir, &id, MARK_SUFFIX);
            // Locked before it has its name: a sweep never sees it unlocked while its run
            // lives. A file system without locks: made all the same (its sweeps cannot
            // lock it either, and leave its set alone). One a sweep holds an instant (it
            // found it half-made) is made again.
            if let Err(fs::TryLockError::WouldBlock) = file.try_lock() {
                let _ = fs::remove_file(&marking);
                if self.id.is_none() {
                    continue;
                }
                return None;
            }
            let linked = fs::hard_link(&marking, &mark);
            let _ = fs::remove_file(&marking);
            match linked {
                Ok(()) => {
                    self.id = Some(id.clone());
                    self.held.push((dir.to_path_buf(), mark, file));
                    return Some(id);
                }
                // Taken by a sweep before it was locked, or the id is another set's.
                Err(_) if self.id.is_none() => continue,
                Err(_) => return None,
            }
        }
        None
    }

    /// Notes in `path`'s folder's mark that the set is about to place the file of inode
    /// `ino` at `path`: a sweep puts the kept file back only over that one.
    fn note_placing(&mut self, path: &Path, ino: u64) {
        let dir = folder_of(path);
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if let Some((.., f)) = self.held.iter_mut().find(|(d, ..)| d == dir) {
            let _ = writeln!(f, "{ino} {name}");
        }
    }

    /// Lets go of the marks without removing them: a file could not be put back, and its
    /// link stays for the next sweep.
    fn abandon(self) {}

    /// The renames are done (or undone): from here a kill leaves this set's files as they
    /// are, and its links are only removed.
    fn finish(self) {
        for (_, path, file) in self.held {
            let _ = fs::remove_file(&path);
            drop(file);
        }
    }
}

/// How a mark is opened for writing, readable by others.
fn mark_file() -> fs::OpenOptions {
    let mut o = fs::OpenOptions::new();
    o.write(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        o.mode(0o644);
    }
    o
}

/// Serialises the renames of sets written into one folder at once. Two runs writing the
/// same output (two renders given one --out) each wrote whole sets of temporaries, but
/// their renames interleaved: one run's image beside the other's report, both exiting 0
/// (4 of 60 tries). Now the last set renamed is the one left, whole. The lock is taken on
/// the folder itself, so no lock file is left behind; where the folder cannot be locked
/// (no such locks on its file system, or not Unix) the renames go unserialised, as before.
///
/// Another program may hold a lock on the folder for long (`flock DIR cmd`, or anyone's on
/// /tmp): after [`FOLDER_LOCK_WAIT`] the renames go ahead without it, with a note.
fn lock_folder(dir: &Path) -> Option<fs::File> {
    let locked = lock_folder_within(dir, FOLDER_LOCK_WAIT);
    if locked.is_err() {
        note(&format!(
            "note: {} stayed locked by another program for {} s; this output's files are \
             renamed into it without waiting (two stcvae runs writing one output at this \
             moment could mix their files)",
            dir.display(),
            FOLDER_LOCK_WAIT.as_secs()
        ));
    }
    locked.ok().flatten()
}

/// How long a set's renames wait for its folder's lock. Another stcvae holds it for the
/// milliseconds of its own renames.
const FOLDER_LOCK_WAIT: std::time::Duration = std::time::Duration::from_secs(5);

/// The folder's lock within `wait`: Ok(None) where it cannot be locked at all, Err(())
/// where it stayed held by another for `wait`.
fn lock_folder_within(dir: &Path, wait: std::time::Duration) -> Result<Option<fs::File>, ()> {
    if !cfg!(unix) {
        return Ok(None);
    }
    let Ok(folder) = fs::File::open(dir) else {
        return Ok(None);
    };
    let start = std::time::Instant::now();
    loop {
        match folder.try_lock() {
            Ok(()) => return Ok(Some(folder)),
            Err(fs::TryLockError::WouldBlock) if start.elapsed() < wait => {
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
            Err(fs::TryLockError::WouldBlock) => return Err(()),
            Err(fs::TryLockError::Error(_)) => return Ok(None),
        }
    }
}

/// What a set's file had before its rename.
enum Before {
    /// Nothing: undoing the rename removes the new file.
    Absent,
    /// A file, kept as a hard link: undoing the rename puts it back.
    Kept(Previous),
    /// A file that could not be linked (a file system without hard links, another user's
    /// file under protected_hardlinks): its replacement cannot be undone, and the new file
    /// is left in its place.
    Unkept,
}

/// A hard link to the file an output replaces, `.NAME.ID.stcvae-previous` (ID: its set's,
/// [`Marks`]), removed when dropped: the set's renames can then be undone. Not in
/// [`LIVE`], as its set's mark is not.
struct Previous {
    link: tempfile::TempPath,
}

impl Previous {
    fn keep(path: &Path, marks: &mut Marks) -> Before {
        if fs::symlink_metadata(path).is_err() {
            return Before::Absent;
        }
        let dir = folder_of(path);
        let Some(id) = marks.in_folder(dir) else {
            return Before::Unkept;
        };
        let link = dir.join(format!("{}{id}{LINK_SUFFIX}", temp_prefix(path)));
        if fs::hard_link(path, &link).is_err() {
            return Before::Unkept;
        }
        match tempfile::TempPath::try_from_path(&link) {
            Ok(link) => Before::Kept(Self { link }),
            // No current folder to resolve a relative path by: not kept after all.
            Err(_) => {
                let _ = fs::remove_file(&link);
                Before::Unkept
            }
        }
    }

    /// Renames the link back over `path`; where that fails the link is kept (dropped, it
    /// took the earlier file's last name with it).
    fn restore(self, path: &Path) -> io::Result<()> {
        self.link.persist(path).map_err(|e| {
            let _ = e.path.keep();
            e.error
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `bytes` written to `path`, last modified a minute ago: a temporary its run left
    /// behind, past [`remove_killed_temporaries`]' few seconds of grace.
    fn left_behind(path: &Path, bytes: &[u8]) {
        fs::write(path, bytes).unwrap();
        let minute_ago = std::time::SystemTime::now() - std::time::Duration::from_secs(60);
        fs::File::options()
            .write(true)
            .open(path)
            .unwrap()
            .set_modified(minute_ago)
            .unwrap();
    }

    /// A temporary left by a killed run (no lock: its process is gone) is removed when the
    /// same output is written again; one another writer holds (here a live `AtomicFile`,
    /// whose lock a second open file conflicts with even in one process) is left, as are
    /// one made an instant ago (maybe another run's, not yet locked), other names'
    /// temporaries and a file that only looks like one.
    #[test]
    fn a_killed_runs_temporary_is_swept_and_a_live_one_kept() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("y.csv");
        let killed = d.path().join(".y.csv.AbC123.partial");
        let other = d.path().join(".z.csv.AbC123.partial");
        let lookalike = d.path().join(".y.csv.seven77.partial");
        let young = d.path().join(".y.csv.Young1.partial");
        for p in [&killed, &other, &lookalike] {
            left_behind(p, b"half a dataset");
        }
        fs::write(&young, b"just made").unwrap();
        let mut live = AtomicFile::create(&out).unwrap();
        // Creating `live` swept the killed run's temporary already.
        assert!(!killed.exists());
        assert!(young.exists());
        let live_tmp: Vec<PathBuf> = fs::read_dir(d.path())
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| ![&other, &lookalike, &young].contains(&p))
            .collect();
        assert_eq!(live_tmp.len(), 1, "{live_tmp:?}");
        left_behind(&killed, b"half a dataset");
        // The live one is as old as the killed one now: its lock alone keeps it.
        fs::File::options()
            .write(true)
            .open(&live_tmp[0])
            .unwrap()
            .set_modified(std::time::SystemTime::now() - std::time::Duration::from_secs(60))
            .unwrap();
        let gone = remove_killed_temporaries(&out, &temp_prefix(&out));
        assert_eq!(gone, vec![(killed.clone(), 14)]);
        assert!(live_tmp[0].exists(), "the live temporary was removed");
        assert!(other.exists() && lookalike.exists() && young.exists());
        live.write_all(b"x").unwrap();
        live.commit().unwrap();
        assert_eq!(fs::read(&out).unwrap(), b"x");
        // Names alike for their first 64 bytes (long shard names) sweep only their own.
        let long = "s".repeat(70);
        let (a, b) = (
            d.path().join(format!("{long}_1.csv")),
            d.path().join(format!("{long}_2.csv")),
        );
        let (pa, pb) = (temp_prefix(&a), temp_prefix(&b));
        assert!(pa != pb && pa.len() == 66 && pb.len() == 66, "{pa} {pb}");
        let killed_b = d.path().join(format!("{pb}AbC123.partial"));
        left_behind(&killed_b, b"x");
        assert!(remove_killed_temporaries(&a, &pa).is_empty());
        assert_eq!(remove_killed_temporaries(&b, &pb), vec![(killed_b, 1)]);
    }

    /// A run killed part way through a set's renames (SIGKILL between them) left the links
    /// to what it replaced for ever, and a mixed set. The next set written into the folder
    /// deals with them by the killed set's mark (`.stcvae-set.ID.renaming`, which notes
    /// each inode the set placed):
    /// - marked, the mark unlocked (its run gone): put back. Here a.exr was replaced (its
    ///   old bytes come back), a.png's link is to the file as it still is (only the link
    ///   goes), the link of a file removed since is removed, and a long name's link finds
    ///   its file by the checksum in its prefix;
    /// - a file replaced since by another run: that run's file stays;
    /// - unmarked (killed after its renames, while removing its links): the new files stay
    ///   and the link goes (putting back the links left would mix the sets);
    /// - marked and locked (being written now): left alone.
    ///
    /// Other programs' files that only look alike stay, and a mark's name without an id
    /// is no mark (it panicked the sweep).
    #[cfg(unix)]
    #[test]
    fn a_killed_sets_replaced_files_are_put_back() {
        use std::os::unix::fs::MetadataExt;
        let d = tempfile::tempdir().unwrap();
        let at = |n: &str| d.path().join(n);
        let long = format!("{}.exr", "l".repeat(70));
        for (n, b) in [
            ("a.exr", "old exr"),
            ("a.png", "old png"),
            (long.as_str(), "old l"),
        ] {
            fs::write(at(n), b).unwrap();
        }
        let link = |n: &str, id: &str| at(&format!("{}{id}.stcvae-previous", temp_prefix(&at(n))));
        let mark = |id: &str| at(&format!(".stcvae-set.{id}.renaming"));
        let ino = |n: &str| fs::metadata(at(n)).unwrap().ino();
        let replace = |n: &str, b: &str| {
            fs::write(at("new"), b).unwrap();
            fs::rename(at("new"), at(n)).unwrap();
        };
        // What the killed set did: marked the folder, kept every predecessor, renamed the
        // new a.exr and long file over theirs (noting each), and was killed before
        // a.png's rename.
        for n in ["a.exr", "a.png", long.as_str()] {
            fs::hard_link(at(n), link(n, "Kil123")).unwrap();
        }
        replace("a.exr", "new exr");
        replace(&long, "new l");
        let noted = format!("{} a.exr\n{} {long}\n", ino("a.exr"), ino(&long));
        fs::write(mark("Kil123"), noted).unwrap();
        fs::write(
            at(".gone.json.Kil123.stcvae-previous"),
            "a file removed since",
        )
        .unwrap();
        let others = [
            ".notes.backup.previous",
            ".stcvae-set.renaming",
            ".a.exr.x.stcvae-previous",
        ];
        for n in others {
            fs::write(at(n), "another program's").unwrap();
        }
        write_atomic_set(&[(&at("b.txt"), b"another output")]).unwrap();
        assert_eq!(fs::read_to_string(at("a.exr")).unwrap(), "old exr");
        assert_eq!(fs::read_to_string(at("a.png")).unwrap(), "old png");
        assert_eq!(fs::read_to_string(at(&long)).unwrap(), "old l");
        let left = || {
            let mut v: Vec<String> = fs::read_dir(d.path())
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .filter(|n| !others.contains(&n.as_str()))
                .collect();
            v.sort();
            v
        };
        let whole = ["a.exr", "a.png", "b.txt", long.as_str()];
        assert_eq!(left(), whole);
        assert!(others.iter().all(|n| at(n).exists()));
        // Killed while removing its links, its renames done: nothing is put back.
        fs::hard_link(at("a.exr"), link("a.exr", "Don456")).unwrap();
        replace("a.exr", "newest exr");
        restore_killed_sets(d.path());
        assert_eq!(fs::read_to_string(at("a.exr")).unwrap(), "newest exr");
        assert_eq!(left(), whole);
        // Killed after placing a.png, which another run replaced since: that run's stays.
        fs::hard_link(at("a.png"), link("a.png", "Rep000")).unwrap();
        replace("a.png", "killed run's png");
        fs::write(mark("Rep000"), format!("{} a.png\n", ino("a.png"))).unwrap();
        replace("a.png", "a later run's png");
        restore_killed_sets(d.path());
        assert_eq!(
            fs::read_to_string(at("a.png")).unwrap(),
            "a later run's png"
        );
        assert_eq!(left(), whole);
        // A set being written now: its mark locked, its link left.
        fs::hard_link(at("a.png"), link("a.png", "Liv789")).unwrap();
        replace("a.png", "live png");
        fs::write(mark("Liv789"), format!("{} a.png\n", ino("a.png"))).unwrap();
        let held = fs::File::open(mark("Liv789")).unwrap();
        held.try_lock().unwrap();
        restore_killed_sets(d.path());
        assert_eq!(fs::read_to_string(at("a.png")).unwrap(), "live png");
        assert!(link("a.png", "Liv789").exists() && mark("Liv789").exists());
        drop(held);
        // Its run gone, the next sweep puts the file back.
        restore_killed_sets(d.path());
        assert_eq!(
            fs::read_to_string(at("a.png")).unwrap(),
            "a later run's png"
        );
        assert_eq!(left(), whole);
    }

    /// A rename that fails part way through a set puts back what the set's earlier renames
    /// replaced: an old file its old bytes, a new name nothing. Nothing else is left in
    /// the folder (no temporaries, no kept predecessors), and a set that succeeds leaves
    /// only its files. A predecessor that could not be linked is not removed on the way
    /// back (its new file stays: the old is gone either way).
    #[test]
    fn a_failed_rename_puts_the_set_back() {
        let d = tempfile::tempdir().unwrap();
        let (a, b, c) = (d.path().join("a"), d.path().join("b"), d.path().join("c"));
        fs::write(&a, b"old a").unwrap();
        fs::write(&c, b"old c").unwrap();
        let set: [(&Path, &[u8]); 3] = [(&a, b"new a"), (&b, b"new b"), (&c, b"new c")];
        let names = || {
            let mut v: Vec<String> = fs::read_dir(d.path())
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            v.sort();
            v
        };
        for fail_at in 0..3 {
            let mut k = 0;
            let (path, e) = write_set_with(
                bytes_of(&set),
                |f| {
                    k += 1;
                    if k == fail_at + 1 {
                        return Err(io::Error::new(io::ErrorKind::PermissionDenied, "refused"));
                    }
                    f.persist()
                },
                Previous::keep,
                || (),
            )
            .unwrap_err();
            assert_eq!(
                (path.as_path(), e.kind()),
                (set[fail_at].0, io::ErrorKind::PermissionDenied)
            );
            assert_eq!(fs::read(&a).unwrap(), b"old a", "failed at {fail_at}");
            assert!(!b.exists(), "failed at {fail_at}");
            assert_eq!(fs::read(&c).unwrap(), b"old c", "failed at {fail_at}");
            assert_eq!(names(), ["a", "c"], "failed at {fail_at}");
        }
        // A predecessor that could not be kept (no hard links there): its replacement
        // stays, rather than removing the file (a, replaced, then c refused).
        let mut k = 0;
        write_set_with(
            bytes_of(&set),
            |f| {
                k += 1;
                if k == 3 {
                    return Err(io::Error::new(io::ErrorKind::PermissionDenied, "refused"));
                }
                f.persist()
            },
            |p, m| {
                if p == a.as_path() {
                    Before::Unkept
                } else {
                    Previous::keep(p, m)
                }
            },
            || (),
        )
        .unwrap_err();
        assert_eq!(fs::read(&a).unwrap(), b"new a");
        assert!(!b.exists());
        assert_eq!(fs::read(&c).unwrap(), b"old c");
        // A set in folders it made: a rename that fails removes them again, the deeper
        // ones made by later files too, renamed or not (an empty new/ was left behind when
        // the second failed, new/a/ when the first did); a set that succeeds keeps them.
        let (x, y, z) = (
            d.path().join("new/x"),
            d.path().join("new/a/y"),
            d.path().join("new/a/b/z"),
        );
        let nested: [(&Path, &[u8]); 3] = [(&x, b"x"), (&y, b"y"), (&z, b"z")];
        for fail_at in 1..=3 {
            let mut k = 0;
            write_set_with(
                bytes_of(&nested),
                |f| {
                    k += 1;
                    if k == fail_at {
                        return Err(io::Error::new(io::ErrorKind::PermissionDenied, "refused"));
                    }
                    f.persist()
                },
                Previous::keep,
                || (),
            )
            .unwrap_err();
            assert!(!d.path().join("new").exists(), "failed at {fail_at}");
        }
        // A set that fails before its renames (here its last file is a folder, refused)
        // removes the folders too: new/ stayed, its second file's temporary still in it
        // when the first file's folders were removed.
        let folder = d.path().join("folder");
        fs::create_dir(&folder).unwrap();
        let unwritable: [(&Path, &[u8]); 3] = [(&x, b"x"), (&y, b"y"), (&folder, b"f")];
        let (at, _) = write_atomic_set(&unwritable).unwrap_err();
        assert_eq!(at, folder);
        assert!(!d.path().join("new").exists());
        fs::remove_dir(&folder).unwrap();
        // Through a missing folder and back out of it: refused before any folder is made
        // (the existing folder it names was once removed when empty, `gone` left behind).
        let old = d.path().join("old");
        fs::create_dir(&old).unwrap();
        let through = d.path().join("gone/../old/w");
        let round: [(&Path, &[u8]); 1] = [(&through, b"w")];
        let (at, e) = write_atomic_set(&round).unwrap_err();
        assert_eq!(at, through);
        assert!(e.to_string().contains("which does not exist yet"), "{e}");
        assert!(old.is_dir(), "an existing folder removed");
        assert!(!d.path().join("gone").exists());
        fs::remove_dir(&old).unwrap();
        write_atomic_set(&nested).unwrap();
        assert_eq!(
            [&x, &y, &z].map(|p| fs::read(p).unwrap()),
            [b"x", b"y", b"z"].map(|b| b.to_vec())
        );
        fs::remove_dir_all(d.path().join("new")).unwrap();
        write_atomic_set(&set).unwrap();
        for (p, bytes) in set {
            assert_eq!(fs::read(p).unwrap(), bytes);
        }
        assert_eq!(names(), ["a", "b", "c"]);
    }

    /// Outputs never replace what is not a regular file or a link: a FIFO stays a FIFO (as
    /// root a device node would have become a file); a link, dangling or not, is replaced
    /// by the output and its target is left as it was.
    #[cfg(unix)]
    #[test]
    fn outputs_replace_only_files_and_links() {
        use std::os::unix::fs::FileTypeExt;
        let d = tempfile::tempdir().unwrap();
        let fifo = d.path().join("pipe.csv");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            let e = check_output_path(&fifo).unwrap_err();
            assert!(
                e.contains("pipe.csv exists and is not a regular file"),
                "{e}"
            );
            let e = write_atomic(&fifo, b"x").unwrap_err();
            assert!(e.to_string().contains("not a regular file"), "{e}");
            assert!(fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
        } else {
            eprintln!("skipped: the FIFO case (no mkfifo here)");
        }
        let file = d.path().join("real.bin");
        fs::write(&file, b"old").unwrap();
        let nowhere = d.path().join("nowhere");
        for (name, to) in [("link.bin", &file), ("dangling.bin", &nowhere)] {
            let link = d.path().join(name);
            std::os::unix::fs::symlink(to, &link).unwrap();
            check_output_path(&link).unwrap();
            write_atomic(&link, b"new").unwrap();
            assert!(fs::symlink_metadata(&link).unwrap().file_type().is_file());
            assert_eq!(fs::read(&link).unwrap(), b"new");
        }
        assert_eq!(fs::read(&file).unwrap(), b"old");
        assert!(!nowhere.exists());
    }

    /// Nothing is renamed into /dev, /proc or /sys (checked without writing), nor a folder
    /// made in /dev; a folder below /dev that holds files, such as /dev/shm, is let
    /// through.
    #[cfg(target_os = "linux")]
    #[test]
    fn system_folders_are_refused() {
        for (out, named) in [
            ("/dev/stdout", "is in /dev, a folder of devices"),
            ("/dev/stderr", "is in /dev, a folder of devices"),
            ("/dev/render.exr", "is in /dev, a folder of devices"),
            ("/proc/self/render.exr", "is in /proc/self, that is /proc/"),
            ("/sys/render.exr", "is in /sys, a folder of devices"),
            ("/dev/new/render.exr", "is in /dev/new, a folder of devices"),
        ] {
            let e = check_output_path(Path::new(out)).unwrap_err();
            assert!(e.starts_with(&format!("{out} {named}")), "{e}");
            assert!(AtomicFile::create(Path::new(out)).is_err(), "{out}");
        }
        if Path::new("/dev/fd").exists() {
            let e = check_output_path(Path::new("/dev/fd/1")).unwrap_err();
            assert!(e.contains("is in /dev/fd, that is /proc/"), "{e}");
        }
        let shm = Path::new("/dev/shm");
        if shm.is_dir() {
            assert!(check_replaceable(&shm.join("render.exr")).is_ok());
        }
    }

    /// Two writers of one set at once leave one writer's set whole, never a mix: the
    /// renames are serialised on the folder. Without the lock, 4 of 60 pairs of renders
    /// mixed; here each of 300 rounds races two threads, so a lock that did not hold would
    /// show up many times over.
    #[test]
    fn sets_written_at_once_stay_whole() {
        let d = tempfile::tempdir().unwrap();
        let names: Vec<PathBuf> = ["a.exr", "a.png", "a.json"]
            .iter()
            .map(|n| d.path().join(n))
            .collect();
        for round in 0..300 {
            std::thread::scope(|s| {
                for who in [b"1", b"2"] {
                    let names = &names;
                    s.spawn(move || {
                        let files: Vec<(&Path, &[u8])> =
                            names.iter().map(|n| (n.as_path(), &who[..])).collect();
                        write_atomic_set(&files).unwrap();
                    });
                }
            });
            let got: Vec<Vec<u8>> = names.iter().map(|n| fs::read(n).unwrap()).collect();
            assert!(got.iter().all(|g| *g == got[0]), "round {round}: {got:?}");
        }
        assert_eq!(
            fs::read_dir(d.path()).unwrap().count(),
            3,
            "temporaries left"
        );
    }

    /// A folder another program keeps locked holds a set's renames up only for the wait
    /// given, then they go ahead (`flock DIR cmd` around a run hung it for ever); once the
    /// lock is let go it is taken.
    #[cfg(unix)]
    #[test]
    fn a_folder_locked_by_another_is_waited_for_only_so_long() {
        let d = tempfile::tempdir().unwrap();
        let other = fs::File::open(d.path()).unwrap();
        other.lock().unwrap();
        let wait = std::time::Duration::from_millis(50);
        assert!(lock_folder_within(d.path(), wait).is_err());
        drop(other);
        assert!(matches!(lock_folder_within(d.path(), wait), Ok(Some(_))));
    }

    /// A target whose name is as long as names get (255 bytes, multi-byte characters
    /// across the temporary's cut) is written: the temporary's name is shorter than it.
    #[test]
    fn the_longest_names_are_written() {
        let d = tempfile::tempdir().unwrap();
        for name in ["a".repeat(255), format!("a{}.ex", "é".repeat(125))] {
            assert!(name.len() >= 253, "{}", name.len());
            let p = d.path().join(&name);
            write_atomic(&p, b"x").unwrap();
            assert_eq!(fs::read(&p).unwrap(), b"x");
        }
        write_atomic_set(&[(&d.path().join("b".repeat(250)), b"y")]).unwrap();
        let left = fs::read_dir(d.path()).unwrap().count();
        assert_eq!(left, 3, "temporaries left behind");
        // Replacing a long name in a set keeps its predecessor as a link until the set is
        // in place (the link's name had the same limit): a failed second rename puts the
        // first file back.
        let long = d.path().join("c".repeat(250));
        fs::write(&long, b"old").unwrap();
        let mut renames = 0;
        let e = write_set_with(
            bytes_of(&[(&long, b"new"), (&d.path().join("second"), b"z")]),
            |f| {
                renames += 1;
                if renames == 2 {
                    Err(io::Error::other("the second rename fails"))
                } else {
                    f.persist()
                }
            },
            Previous::keep,
            || (),
        );
        assert!(e.is_err());
        assert_eq!(fs::read(&long).unwrap(), b"old");
    }

    /// A sticky folder keeps others' files from all but their owner, the folder's and root.
    #[cfg(unix)]
    #[test]
    fn a_sticky_folder_keeps_other_users_files() {
        let (me, other, root) = (1000, 1001, 0);
        assert!(sticky_keeps(me, 0o41777, root, other));
        assert!(!sticky_keeps(me, 0o41777, root, me), "my own file");
        assert!(!sticky_keeps(me, 0o41777, me, other), "my own folder");
        assert!(!sticky_keeps(root, 0o41777, other, other), "root");
        assert!(!sticky_keeps(me, 0o40777, root, other), "no sticky bit");
    }

    /// An immutable target, or an append-only folder, fails the rename at the end of the
    /// work, even as root: refused before it. Setting the flags needs root on a file system
    /// that keeps them (ext4 here); elsewhere the test says so and checks nothing.
    #[cfg(target_os = "linux")]
    #[test]
    fn an_immutable_target_is_refused_before_the_work() {
        let d = tempfile::tempdir().unwrap();
        let f = d.path().join("kept.exr");
        fs::write(&f, b"x").unwrap();
        check_output_path(&f).unwrap();
        let set = std::process::Command::new("chattr")
            .arg("+i")
            .arg(&f)
            .output();
        if !set.as_ref().is_ok_and(|o| o.status.success()) {
            eprintln!("skipped: chattr +i failed here (not root, or no such flag): {set:?}");
            return;
        }
        let r = check_output_path(&f);
        let unset = std::process::Command::new("chattr")
            .arg("-i")
            .arg(&f)
            .status();
        assert!(unset.is_ok_and(|s| s.success()), "chattr -i");
        let e = r.unwrap_err();
        assert!(e.contains("kept.exr is immutable or append-only"), "{e}");
        check_output_path(&f).unwrap();
        // An append-only folder takes new files but lets none be renamed or removed: the
        // output failed after the work and left the probe and its temporary there.
        let folder = d.path().join("log");
        fs::create_dir(&folder).unwrap();
        let chattr = |flag: &str, p: &Path| {
            std::process::Command::new("chattr")
                .arg(flag)
                .arg(p)
                .status()
                .is_ok_and(|s| s.success())
        };
        assert!(chattr("+a", &folder), "chattr +a");
        let r = check_output_path(&folder.join("new.bin"));
        let left = fs::read_dir(&folder).unwrap().count();
        assert!(chattr("-a", &folder), "chattr -a");
        let e = r.unwrap_err();
        assert!(e.contains("log is immutable or append-only"), "{e}");
        assert_eq!(left, 0, "the probe was left in the folder");
        // Reached through a link, the same (the link was not followed, and the check
        // skipped); but a folder still to be made in it takes the output, and no probe.
        let link = d.path().join("loglink");
        std::os::unix::fs::symlink(&folder, &link).unwrap();
        assert!(chattr("+a", &folder), "chattr +a");
        let through = check_output_path(&link.join("y.bin"));
        let below = check_output_path(&folder.join("new/z.bin"));
        let left = fs::read_dir(&folder).unwrap().count();
        assert!(chattr("-a", &folder), "chattr -a");
        let e = through.unwrap_err();
        assert!(e.contains("loglink is immutable or append-only"), "{e}");
        below.unwrap();
        assert_eq!(left, 0, "the probe was left in the folder");
    }

    #[test]
    fn output_paths_are_checked_before_the_work() {
        let d = tempfile::tempdir().unwrap();
        let file = d.path().join("afile");
        fs::write(&file, b"x").unwrap();
        // A file where a directory should be, however deep the path goes on below it.
        for p in [file.join("out.bin"), file.join("a/b/out.bin")] {
            let e = check_output_path(&p).unwrap_err();
            assert!(e.contains("afile exists and is not a directory"), "{e}");
        }
        let e = check_output_path(d.path()).unwrap_err();
        assert!(e.ends_with("is a directory"), "{e}");
        let e = check_output_path(&d.path().join("new/")).unwrap_err();
        assert!(
            e.ends_with("ends with a path separator: name a file"),
            "{e}"
        );
        // Directories still to be made are fine, and the probe leaves nothing behind.
        check_output_path(&d.path().join("new/deeper/out.bin")).unwrap();
        let left: Vec<_> = fs::read_dir(d.path()).unwrap().collect();
        assert_eq!(left.len(), 1, "{left:?}");
        // A `..` after a folder not made yet named a file no check saw (an input beside
        // it): refused, naming the folder, and nothing is made.
        let e = check_output_path(&d.path().join("new/../afile")).unwrap_err();
        assert!(e.contains("new, which does not exist yet"), "{e}");
        let e = check_output_path(&d.path().join("a/b/../../../dev/x")).unwrap_err();
        assert!(e.contains("a, which does not exist yet"), "{e}");
        assert!(!d.path().join("new").exists() && !d.path().join("a").exists());
        // A file on the way is named as what it is, `..` or not.
        let e = check_output_path(&file.join("sub/../x")).unwrap_err();
        assert!(e.contains("afile exists and is not a directory"), "{e}");
        // A folder to write into is judged as a folder: the made-up file name its check
        // once used (`file`) was judged as a target, so a folder holding a folder of that
        // name was refused as "is a directory".
        fs::create_dir_all(d.path().join("ck/file")).unwrap();
        check_output_folder(&d.path().join("ck")).unwrap();
        check_output_folder(&d.path().join("ck/new/deeper")).unwrap();
        let e = check_output_folder(&d.path().join("new/../ck")).unwrap_err();
        assert!(e.contains("new, which does not exist yet"), "{e}");
        let e = check_output_folder(&file).unwrap_err();
        assert!(e.contains("afile exists and is not a directory"), "{e}");
        fs::remove_dir_all(d.path().join("ck")).unwrap();
        // Through folders that exist, `..` is an ordinary path.
        fs::create_dir(d.path().join("sub")).unwrap();
        check_output_path(&d.path().join("sub/../y.bin")).unwrap();
        fs::remove_dir(d.path().join("sub")).unwrap();
        #[cfg(unix)]
        {
            // The system's own errors follow a colon (the message ran on from the name).
            let (a, b) = (d.path().join("loopA"), d.path().join("loopB"));
            std::os::unix::fs::symlink(&b, &a).unwrap();
            std::os::unix::fs::symlink(&a, &b).unwrap();
            let e = check_output_path(&a.join("x.exr")).unwrap_err();
            assert!(e.contains("x.exr: Too many levels"), "{e}");
            fs::remove_file(&a).unwrap();
            fs::remove_file(&b).unwrap();
        }
        #[cfg(unix)]
        {
            let link = d.path().join("gone");
            std::os::unix::fs::symlink(d.path().join("nowhere"), &link).unwrap();
            let e = check_output_path(&link.join("out.bin")).unwrap_err();
            assert!(e.contains("gone is a symbolic link to nothing"), "{e}");
            fs::remove_file(&link).unwrap();
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let ro = d.path().join("ro");
            fs::create_dir(&ro).unwrap();
            fs::set_permissions(&ro, fs::Permissions::from_mode(0o555)).unwrap();
            // root may write anywhere: the check is only meaningful for other users.
            let root = tempfile::tempfile_in(&ro).is_ok();
            let r = check_output_path(&ro.join("out.bin"));
            fs::set_permissions(&ro, fs::Permissions::from_mode(0o755)).unwrap();
            if !root {
                let e = r.unwrap_err();
                assert!(e.contains("cannot create files in"), "{e}");
            }
            // root may write anywhere on disk, but not into /proc/self (CI may run as root):
            // this branch runs for every user on Linux.
            #[cfg(target_os = "linux")]
            {
                let e = check_output_path(Path::new("/proc/self/out.bin")).unwrap_err();
                assert!(e.contains("a folder of devices and kernel entries"), "{e}");
            }
        }
    }

    /// Each temporary is registered in `LIVE` (for a second Ctrl-C's exit to remove) under
    /// its own name while it is written, and only then: a target registered instead (the
    /// user's earlier output) would be removed by that exit, and a dropped temporary's
    /// entry, and only its own, goes. Only this test's own paths are looked at, as other
    /// tests write at the same time (remove_live_temporaries is not called for that reason).
    #[test]
    fn a_temporary_is_registered_while_it_is_written() {
        let d = tempfile::tempdir().unwrap();
        let registered = |p: &Path| {
            LIVE.lock()
                .unwrap_or_else(|e| e.into_inner())
                .iter()
                .any(|q| q.as_path() == p)
        };
        let (a_out, b_out) = (d.path().join("a.exr"), d.path().join("b.exr"));
        fs::write(&a_out, b"old a").unwrap();
        let a = AtomicFile::create(&a_out).unwrap();
        let b = AtomicFile::create(&b_out).unwrap();
        let a_tmp = a.writer.get_ref().0.path().to_path_buf();
        let b_tmp = b.writer.get_ref().0.path().to_path_buf();
        assert!(
            registered(&a_tmp) && registered(&b_tmp),
            "a temporary was not registered"
        );
        assert!(
            !registered(&a_out) && !registered(&b_out),
            "a target registered"
        );
        drop(a);
        assert!(!registered(&a_tmp), "a dropped temporary stayed registered");
        assert!(registered(&b_tmp), "a live temporary was unregistered");
        b.commit().unwrap();
        assert!(!registered(&b_tmp), "still registered after its commit");
        assert_eq!(fs::read(&a_out).unwrap(), b"old a");
    }

    /// An input that is a socket is refused by name, as a FIFO or a device is: opening it
    /// fails with "No such device or address", which names no cause.
    #[cfg(unix)]
    #[test]
    fn an_input_that_is_a_socket_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let sock = d.path().join("scene.toml");
        // Skipped only where the temporary folder's path is too long for a socket's address
        // (108 bytes, `InvalidInput`); any other failure to make one fails the test, which
        // would otherwise pass having checked nothing.
        let _listener = match std::os::unix::net::UnixListener::bind(&sock) {
            Ok(l) => l,
            Err(e) if e.kind() == io::ErrorKind::InvalidInput => {
                eprintln!("skipped: {} is too long for a socket: {e}", sock.display());
                return;
            }
            Err(e) => panic!("no socket could be made at {}: {e}", sock.display()),
        };
        let e = check_input(&sock).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput);
        assert!(e.to_string().contains("is a socket, not a file"), "{e}");
        let e = read_input_to_string(&sock).unwrap_err();
        assert!(e.to_string().contains("is a socket, not a file"), "{e}");
        let file = d.path().join("file.toml");
        fs::write(&file, "x").unwrap();
        assert_eq!(read_input_to_string(&file).unwrap(), "x");
    }

    /// What an aborted write left beside an output only one command writes (a training's
    /// checkpoint files) is removed before it is written again: its temporaries
    /// (`.NAME.XXXXXX.partial`) and the links of versions before the sets' marks
    /// (`.NAME.XXXXXX.previous`). Another output's temporary, a look-alike, a set's link
    /// (`restore_killed_sets`' to deal with) and the output itself stay.
    #[test]
    fn stale_temporaries_and_old_links_are_removed() {
        let d = tempfile::tempdir().unwrap();
        let at = |n: &str| d.path().join(n);
        let out = at("m.bpk");
        fs::write(&out, b"model").unwrap();
        let stale = [".m.bpk.AbC123.partial", ".m.bpk.XyZ987.previous"];
        let kept = [
            ".n.bpk.AbC123.partial",
            ".m.bpk.seven77.previous",
            ".m.bpk.AbC123.stcvae-previous",
        ];
        for n in stale.into_iter().chain(kept) {
            fs::write(at(n), b"x").unwrap();
        }
        remove_stale_temporaries_of(&out);
        for n in stale {
            assert!(!at(n).exists(), "{n} was left");
        }
        for n in kept {
            assert!(at(n).exists(), "{n} was removed");
        }
        assert_eq!(fs::read(&out).unwrap(), b"model");
    }

    /// A set killed after marking its folder but before keeping any file (a mark with no
    /// link beside it), or while making its mark (`….marking`), leaves only marks: the next
    /// sweep removes them all the same (they stayed for ever while no link was there). A
    /// live set's marks (locked) stay.
    #[cfg(unix)]
    #[test]
    fn a_killed_sets_lone_marks_are_removed() {
        let d = tempfile::tempdir().unwrap();
        let at = |n: &str| d.path().join(n);
        fs::write(at("a.exr"), b"a").unwrap();
        let (dead, half) = (
            at(".stcvae-set.Dea123.renaming"),
            at(".stcvae-set.Hal456.marking"),
        );
        let (live, making) = (
            at(".stcvae-set.Liv789.renaming"),
            at(".stcvae-set.Mak000.marking"),
        );
        for m in [&dead, &half, &live, &making] {
            fs::write(m, b"").unwrap();
        }
        let held = [&live, &making].map(|m| {
            let f = fs::File::open(m).unwrap();
            f.try_lock().unwrap();
            f
        });
        restore_killed_sets(d.path());
        assert!(!dead.exists(), "a killed set's mark was left");
        assert!(!half.exists(), "a killed set's half-made mark was left");
        assert!(
            live.exists() && making.exists(),
            "a live set's mark was removed"
        );
        assert_eq!(fs::read(at("a.exr")).unwrap(), b"a");
        drop(held);
    }

    /// A folder to write into that is /dev, /proc or /sys itself is refused as the folder
    /// of devices it is (its own place is judged, not its parent's: `/`, which let `/dev`
    /// through to the probe, and as root to the work).
    #[cfg(target_os = "linux")]
    #[test]
    fn a_system_folder_is_refused_as_an_output_folder() {
        // (A sandbox may lack /proc or /sys, not all three: a run that checked none fails.)
        let mut checked = 0;
        for dir in ["/dev", "/proc", "/sys"] {
            if !Path::new(dir).is_dir() {
                continue;
            }
            checked += 1;
            let e = check_output_folder(Path::new(dir)).unwrap_err();
            assert!(
                e.starts_with(&format!(
                    "{dir} is in {dir}, a folder of devices and kernel entries"
                )),
                "{e}"
            );
        }
        assert!(checked > 0, "none of /dev, /proc and /sys is a folder here");
    }
}
