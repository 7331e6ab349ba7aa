//! The hidden temporaries outputs are written to: named beside their target, locked
//! while written, registered so an abort removes them, and swept when a killed run left
//! them.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};

use tempfile::NamedTempFile;

use super::{folder_of, note};

/// The temporaries being written now, so that an abort that skips destructors (a second
/// Ctrl-C calls `exit`) can still remove them: each is registered while its guard lives.
pub(super) static LIVE: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

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
/// `.NAME.XXXXXX.partial` files) and says so: a second Ctrl-C exits without destructors, and a
/// temporary made in the instant before its registration in `LIVE` is missed. For outputs only one
/// command writes at a time (a training's checkpoints), called before it writes them again; the
/// links a killed set left are [`restore_killed_sets`](super::restore_killed_sets)'.
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
pub(super) fn locked_temporary(
    builder: &tempfile::Builder,
    dir: &Path,
) -> io::Result<NamedTempFile> {
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

/// Removes the `.NAME.XXXXXX.partial` temporaries beside `path` (`prefix` is [`temp_prefix`]'s)
/// that no process is writing, and returns them with their sizes. Each writer holds a lock on its
/// temporary ([`AtomicFile::create`](super::AtomicFile::create)), which the OS releases when the
/// process dies, so one whose lock can be taken was left by a run that was killed (SIGKILL, the OOM
/// killer, a power cut) before any handler could remove it: a killed `generate` left a hidden
/// `.y.csv.XXXXXX.partial` that no later run removed or named, and a dataset's holds hundreds of
/// MB. A temporary another run is writing keeps its lock and is left alone.
pub(super) fn remove_killed_temporaries(path: &Path, prefix: &str) -> Vec<(PathBuf, u64)> {
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

/// The start of a temporary's name beside `path` (".NAME."): at most 64 bytes standing for
/// the target's name, so that the temporary stays within a file system's 255-byte names
/// whenever the target's name does (the whole name plus ".XXXXXX.partial" failed for names
/// of 236–255 bytes, after the work was done).
pub(super) fn temp_prefix(path: &Path) -> String {
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
