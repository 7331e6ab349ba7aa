//! The marks a set leaves while it renames, and the undoing of a set that a kill cut
//! short ([`restore_killed_sets`]).

use std::collections::HashMap;
use std::fs;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use super::temporaries::temp_prefix;
use super::{folder_of, note};

/// A set's mark's name ([`Marks`]): `.stcvae-set.ID.renaming`, made as `….marking`.
const MARK_PREFIX: &str = ".stcvae-set.";
const MARK_SUFFIX: &str = ".renaming";
const MARKING_SUFFIX: &str = ".marking";

/// A kept file's link is its temporaries' prefix, the set's id and this: a suffix of its
/// own, so that no other program's `.x.backup.previous` is taken for one.
pub(super) const LINK_SUFFIX: &str = ".stcvae-previous";

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

/// A set's mark in each folder where it keeps a file it replaces, while its renames are under way
/// ([`restore_killed_sets`]): `.stcvae-set.ID.renaming`, locked from before it can be seen (made as
/// `….marking`, locked, then linked to its name) until its renames are done or undone, when it is
/// removed (the OS drops the lock when the process dies; a rollback that could not put a file back
/// leaves it, [`Marks::abandon`]). Before each rename the set notes in it the inode it is about to
/// place and the file's name. Not in [`LIVE`](super::temporaries::LIVE): a second Ctrl-C's exit
/// leaves it, so that the next set written there puts the killed one's files back.
pub(super) struct Marks {
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
    pub(super) fn new() -> Self {
        Self {
            id: None,
            held: Vec::new(),
        }
    }

    /// The set's id, its folder `dir` marked (once); None where no mark can be made
    /// there, and the file it would keep is then not kept.
    pub(super) fn in_folder(&mut self, dir: &Path) -> Option<String> {
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
    pub(super) fn note_placing(&mut self, path: &Path, ino: u64) {
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
    pub(super) fn abandon(self) {}

    /// The renames are done (or undone): from here a kill leaves this set's files as they
    /// are, and its links are only removed.
    pub(super) fn finish(self) {
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
