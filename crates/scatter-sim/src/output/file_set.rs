//! Several output files written as one: every temporary complete before the first
//! rename, and the files they replace kept until the last, so that a failure puts the
//! set back.

use std::fs;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use super::atomic_file::{AtomicFile, Finished, MadeDirs};
use super::set_marks::{LINK_SUFFIX, Marks, restore_killed_sets};
use super::temporaries::temp_prefix;
use super::{folder_of, note};

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
pub(super) fn bytes_of<'a>(files: &[(&'a Path, &'a [u8])]) -> Vec<(&'a Path, Contents<'a>)> {
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
pub(super) fn write_set_with(
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
pub(super) fn lock_folder_within(
    dir: &Path,
    wait: std::time::Duration,
) -> Result<Option<fs::File>, ()> {
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
pub(super) enum Before {
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
/// [`LIVE`](super::temporaries::LIVE), as its set's mark is not.
pub(super) struct Previous {
    link: tempfile::TempPath,
}

impl Previous {
    pub(super) fn keep(path: &Path, marks: &mut Marks) -> Before {
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
