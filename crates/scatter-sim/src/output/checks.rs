//! Paths checked before the work: an output that can be written, renamed into place and
//! replaced, and an input that can be read without waiting for ever.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};

use tempfile::NamedTempFile;

use super::folder_of;

/// Checks, before long work starts, that [`AtomicFile::create`](super::AtomicFile::create) will be
/// able to write `path`: the nearest existing ancestor of its directory is a directory in which
/// files can be created (probed with a temporary file, removed at once) and renamed (its flags),
/// and `path` is a file the final rename can replace ([`check_replaceable`]; nor another user's
/// file in a sticky folder, nor an immutable one). Otherwise the message says which part of the
/// path is at fault, e.g. "x exists and is not a directory" instead of the "File exists" that
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
pub(super) fn sticky_keeps(me: u32, folder_mode: u32, folder_owner: u32, file_owner: u32) -> bool {
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
