//! One output file written to a temporary and renamed over its target once complete.

use std::fs;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use tempfile::NamedTempFile;

use super::checks::check_replaceable;
use super::temporaries::{Live, locked_temporary, remove_killed_temporaries, temp_prefix};
use super::{folder_of, note};

/// A buffered writer to a temporary file that becomes `path` on [`AtomicFile::commit`].
pub struct AtomicFile {
    path: PathBuf,
    pub(super) writer: BufWriter<Temporary>,
    live: Live,
    // Last: dropped after the temporary file, whose folder is then empty.
    made: MadeDirs,
}

/// The folders [`AtomicFile::create`] made for its target, deepest first: removed again
/// (each only while empty) when the file is dropped uncommitted, since an interrupted
/// `generate --out new/sub/x.bin` left `new/sub/` behind. A run aborted by a second Ctrl-C
/// still leaves them (its temporary files are removed, nothing else is).
pub(super) struct MadeDirs(pub(super) Vec<PathBuf>);

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
    pub(super) fn finish(self) -> io::Result<Finished> {
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
pub(super) struct Temporary(pub(super) NamedTempFile);

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
pub(super) struct Finished {
    pub(super) tmp: NamedTempFile,
    pub(super) path: PathBuf,
    _live: Live,
    // Last: the folders go only if the rename does not happen.
    pub(super) made: MadeDirs,
}

impl Finished {
    pub(super) fn persist(mut self) -> io::Result<()> {
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
