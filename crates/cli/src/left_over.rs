//! Files an earlier run left in a results folder that this run did not write again.
//!
//! `experiment` and `eval` write into one folder per run; a second run with fewer
//! densities or other settings rewrites only its own files, and the first run's others
//! stayed beside them unsaid (k2–k8 images next to a report of k1 alone). They are named,
//! not deleted: the folder may hold what the user put there, and an expensive full run's
//! images should not go because a quick one followed.

use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// The files directly in a folder, each with what changes when it is written again
/// (outputs are written to a temporary and renamed: a new inode and modification time).
pub(crate) struct Snapshot {
    dir: PathBuf,
    files: Vec<(String, Identity)>,
}

#[derive(PartialEq)]
struct Identity {
    modified: Option<SystemTime>,
    inode: u64,
    len: u64,
}

fn identity(path: &Path) -> Option<Identity> {
    let m = std::fs::symlink_metadata(path).ok()?;
    if !m.is_file() {
        return None;
    }
    #[cfg(unix)]
    let inode = std::os::unix::fs::MetadataExt::ino(&m);
    #[cfg(not(unix))]
    let inode = 0;
    Some(Identity {
        modified: m.modified().ok(),
        inode,
        len: m.len(),
    })
}

impl Snapshot {
    /// The folder's files now (none if it does not exist); hidden files are left out.
    pub(crate) fn take(dir: &Path) -> Self {
        Self::take_matching(dir, |_| true)
    }

    /// The folder's files whose names `ours` accepts: the names a command writes, where
    /// its folder may hold the user's own files (`eval --out .` named a config and a CSV
    /// beside its metrics as "of an earlier run" to delete).
    pub(crate) fn take_matching(dir: &Path, ours: impl Fn(&str) -> bool) -> Self {
        let files = std::fs::read_dir(dir)
            .into_iter()
            .flatten()
            .flatten()
            .filter_map(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                (!name.starts_with('.') && ours(&name))
                    .then(|| identity(&e.path()).map(|id| (name, id)))
                    .flatten()
            })
            .collect();
        Self {
            dir: dir.to_path_buf(),
            files,
        }
    }

    /// The files of the snapshot still there unchanged, sorted: what this run did not
    /// write again.
    pub(crate) fn left_over(&self) -> Vec<String> {
        let mut names: Vec<String> = self
            .files
            .iter()
            .filter(|(name, id)| identity(&self.dir.join(name)).as_ref() == Some(id))
            .map(|(name, _)| name.clone())
            .collect();
        names.sort();
        names
    }

    /// Says which files an earlier run left (at most 12 named), if any.
    pub(crate) fn note_left_over(&self, what: &str) {
        let names = self.left_over();
        if names.is_empty() {
            return;
        }
        let shown: Vec<String> = names
            .iter()
            .take(12)
            .map(|n| scatter_sim::ranges::printable(n))
            .collect();
        let more = names.len().saturating_sub(shown.len());
        eprintln!(
            "note: {} also holds {} file{} of an earlier run that this one did not write \
             (not in its {what}): {}{}; delete them, or give each run its own --out",
            crate::paths::shown(&self.dir),
            names.len(),
            if names.len() == 1 { "" } else { "s" },
            shown.join(", "),
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            }
        );
    }
}
