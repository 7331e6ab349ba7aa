//! The cache of distance grids and escape cones between runs: where it lives, how its
//! files are named (by mesh and by the code that computes them), and how it is kept from
//! growing without end.

use std::path::{Path, PathBuf};
use std::time::SystemTime;

use crate::geometry::Geometry;
use crate::hash::Fnv64;

/// The code that computes what is cached (a hash of its sources, build.rs): the last part
/// of every cache file's name.
const CODE: &str = env!("STCVAE_CACHE_CODE");

/// The cache file of `stem` (what is cached, of which mesh) as this code computes it.
pub(crate) fn cache_file(stem: &str) -> Option<PathBuf> {
    cache_dir().map(|d| d.join(format!("{stem}-{CODE}.bin")))
}

/// Removes the files of `path`'s stem that other code wrote: no build of this code can
/// read them, and a grid is up to tens of MB.
pub(crate) fn prune_stale(path: &Path) {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else {
        return;
    };
    let name = name.to_string_lossy();
    let Some(stem) = name.strip_suffix(&format!("-{CODE}.bin")) else {
        return;
    };
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let other = e.file_name();
        let other = other.to_string_lossy();
        let code = other
            .strip_prefix(stem)
            .and_then(|r| r.strip_prefix('-'))
            .and_then(|r| r.strip_suffix(".bin"));
        if code.is_some_and(|c| c != CODE && is_code(c)) {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// A hasher fed with `tag` and the mesh (vertex positions and triangles): the key of what
/// is cached for a mesh.
pub(crate) fn mesh_hasher(geo: &Geometry, tag: &[u8]) -> Fnv64 {
    let mut h = Fnv64::new();
    h.write(tag);
    for p in &geo.mesh.positions {
        for x in p.to_array() {
            h.write(&x.to_le_bytes());
        }
    }
    for t in &geo.mesh.triangles {
        for i in t {
            h.write(&i.to_le_bytes());
        }
    }
    h
}

/// Says once a run that a cache file could not be written: a render that rebuilt its
/// grid every time (an unwritable ~/.cache) was a second slower with no word why.
pub(crate) fn note_unwritable_cache(path: &Path, e: &std::io::Error) {
    // STCVAE_CACHE naming a file gave "File exists (os error 17)", from making the folder.
    let folder = path.parent().filter(|d| d.exists() && !d.is_dir());
    let why = match folder {
        Some(d) => format!("{} is not a folder", d.display()),
        None => e.to_string(),
    };
    note_once(&format!(
        "note: cannot write the cache file {} ({why}): what it holds is rebuilt every run; \
         set STCVAE_CACHE to a writable folder with room to keep it",
        path.display()
    ));
}

/// Says once a run that there is no cache folder at all (HOME unset, and neither
/// STCVAE_CACHE nor XDG_CACHE_HOME set to one): grids were rebuilt every run without a
/// word, seconds each for the bunny.
fn note_no_cache_folder() {
    note_once(
        "note: no cache folder (STCVAE_CACHE is unset or empty, and XDG_CACHE_HOME and HOME \
         are unset, empty or relative): distance grids and escape cones are rebuilt every run; set \
         STCVAE_CACHE to a folder to keep them",
    );
}

/// One cache note a run, the first that comes.
fn note_once(text: &str) {
    static SAID: std::sync::Once = std::sync::Once::new();
    SAID.call_once(|| scatter_sim::output::note(text));
}

/// Says that a cache entry exists but cannot be used (damaged, truncated, or another
/// mesh's copied under its name) and is being rebuilt: the render was seconds slower than
/// the one before with no word why. The entry is removed first: on a full disk its
/// replacement could not be written while it held its space (23 MB for the bunny's grid),
/// and it was rebuilt every run. Returns whether there was one: the rebuilt entry then
/// replaces it however quickly it was built, or the note would come back every run.
pub(crate) fn note_unusable_entry(path: &Path) -> bool {
    // A folder or other non-file in the entry's place is not the entry (and a write
    // cannot replace it: said by the write's own note).
    let exists = std::fs::symlink_metadata(path).is_ok_and(|m| m.is_file() || m.is_symlink());
    if exists {
        let _ = std::fs::remove_file(path);
        scatter_sim::output::note(&format!(
            "note: the cache file {} is damaged or not this mesh's: rebuilding it",
            path.display()
        ));
    }
    exists
}

/// Results that took longer than this to compute are cached: reading a cached grid takes
/// ~10 ms; the default bunny's grid took 0.85 s to build on 2 cores, a quarter of the
/// default render, when only grids over a second were cached.
pub(crate) const CACHED_FROM_SECONDS: f64 = 0.1;

/// The one way a cache entry is used: read from `path` when it is usable (and marked
/// used), else built, and written when the build took over `cached_from` seconds or an
/// unusable entry is in its place. `path` None: no cache.
pub(crate) fn read_or_build<T, E>(
    path: Option<&Path>,
    cached_from: f64,
    read: impl FnOnce(&Path) -> Option<T>,
    build: impl FnOnce() -> Result<T, E>,
    write: impl FnOnce(&Path, &T) -> std::io::Result<()>,
) -> Result<T, E> {
    let mut unusable = false;
    if let Some(p) = path {
        if let Some(v) = read(p) {
            touch(p);
            return Ok(v);
        }
        unusable = note_unusable_entry(p);
    }
    let t0 = std::time::Instant::now();
    let v = build()?;
    if t0.elapsed().as_secs_f64() > cached_from || unusable {
        match path {
            // A cache that cannot be written only costs time next run; said once.
            Some(p) => {
                if let Err(e) = write(p, &v) {
                    note_unwritable_cache(p, &e);
                }
                tidy(p);
            }
            None => note_no_cache_folder(),
        }
    }
    Ok(v)
}

/// `$STCVAE_CACHE`, else `$XDG_CACHE_HOME/stcvae`, else `~/.cache/stcvae`, the last two
/// only from absolute paths ([`cache_dir_from`]); None: no cache folder.
pub(crate) fn cache_dir() -> Option<PathBuf> {
    cache_dir_from(|k| std::env::var_os(k))
}

/// [`cache_dir`] with the environment read through `var`. An empty variable counts as
/// unset (STCVAE_CACHE="" cached grids in the current directory), and so do a relative
/// XDG_CACHE_HOME or HOME, as the XDG base-directory rules say (a relative one made a
/// cache folder in whatever folder a render ran in). STCVAE_CACHE is this program's own,
/// taken as given.
fn cache_dir_from(var: impl Fn(&str) -> Option<std::ffi::OsString>) -> Option<PathBuf> {
    let set = |k: &str| var(k).filter(|v| !v.is_empty()).map(PathBuf::from);
    if let Some(d) = set("STCVAE_CACHE") {
        return Some(d);
    }
    let absolute = |k: &str| set(k).filter(|d| d.is_absolute());
    if let Some(d) = absolute("XDG_CACHE_HOME") {
        return Some(d.join("stcvae"));
    }
    absolute("HOME").map(|h| h.join(".cache").join("stcvae"))
}

/// Most bytes the cache's entries may hold together. Each object size, mesh and grid
/// resolution is an entry of its own (the bunny's grid ~23 MB at 128, a fine mesh's up to
/// GBs), so a sweep over object heights filled the cache without end (4.1 GB of 113 files
/// here). Past it, the entries used longest ago go; the one just written always stays.
pub const MAX_CACHE_BYTES: u64 = 4_000_000_000;

/// What a cache file's name looks like: `grid-…-CODE.bin` or `cones-…-CODE.bin`, whatever
/// the code that wrote it. Only such files are counted and removed.
fn is_entry(name: &str) -> bool {
    (name.starts_with("grid-") || name.starts_with("cones-"))
        && name
            .strip_suffix(".bin")
            .and_then(|r| r.rsplit_once('-'))
            .is_some_and(|(_, c)| is_code(c))
}

/// Whether `c` has the form of [`CODE`], the hash that ends every cache file's name: 16
/// hex digits.
fn is_code(c: &str) -> bool {
    c.len() == 16 && c.bytes().all(|b| b.is_ascii_hexdigit())
}

/// Marks a cache entry as just used (its modification time, which [`trim`] orders by):
/// reading does not change it where the file system keeps no access times. Best effort:
/// a read-only cache is read all the same.
pub(crate) fn touch(path: &Path) {
    if let Ok(f) = std::fs::File::options().write(true).open(path) {
        let _ = f.set_modified(SystemTime::now());
    }
}

/// After `path` was written: removes its stem's files of other code ([`prune_stale`]),
/// then the entries used longest ago while all of them hold more than
/// [`MAX_CACHE_BYTES`].
pub(crate) fn tidy(path: &Path) {
    prune_stale(path);
    trim(path, MAX_CACHE_BYTES);
}

/// Removes the cache entries beside `keep` used longest ago (oldest modification time
/// first) until those left hold at most `most` bytes; `keep` itself stays whatever its
/// size. An entry another process removed meanwhile counts as removed.
fn trim(keep: &Path, most: u64) {
    let (Some(dir), Some(kept)) = (keep.parent(), keep.file_name()) else {
        return;
    };
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut files: Vec<(SystemTime, u64, PathBuf)> = entries
        .flatten()
        .filter(|e| e.file_name() != kept && is_entry(&e.file_name().to_string_lossy()))
        .filter_map(|e| {
            let m = e.metadata().ok().filter(|m| m.is_file())?;
            Some((m.modified().ok()?, m.len(), e.path()))
        })
        .collect();
    let mut total: u64 =
        files.iter().map(|f| f.1).sum::<u64>() + std::fs::metadata(keep).map_or(0, |m| m.len());
    // Oldest first (ties by name, for a fixed order).
    files.sort_by(|a, b| a.0.cmp(&b.0).then_with(|| a.2.cmp(&b.2)));
    for (_, len, path) in files {
        if total <= most {
            break;
        }
        // Gone already (another run trimming too) frees the space as well.
        match std::fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {}
            _ => total = total.saturating_sub(len),
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, SystemTime};

    use super::{CODE, cache_dir_from, note_unusable_entry, prune_stale, read_or_build, trim};

    /// [`read_or_build`] of a file entry of bytes, with `cached_from` = −1 s (every build
    /// takes longer, so whatever is built is written): the entry's bytes where it holds
    /// any, else `build`'s.
    fn bytes_entry(
        entry: &std::path::Path,
        build: impl FnOnce() -> Result<Vec<u8>, String>,
    ) -> Result<Vec<u8>, String> {
        read_or_build(
            Some(entry),
            -1.0,
            |p| std::fs::read(p).ok(),
            build,
            |p, v| std::fs::write(p, v),
        )
    }

    /// Where the cache lives for each environment: STCVAE_CACHE as given, XDG_CACHE_HOME
    /// and HOME only when absolute (a relative XDG_CACHE_HOME made a cache folder in the
    /// working directory), empty values as unset, and no folder without any.
    #[test]
    fn the_cache_folder_follows_the_xdg_rules() {
        let dir = |vars: &[(&str, &str)]| {
            cache_dir_from(|k| {
                vars.iter()
                    .find(|(n, _)| *n == k)
                    .map(|(_, v)| std::ffi::OsString::from(v))
            })
            .map(|p| p.to_string_lossy().into_owned())
        };
        let home = ("HOME", "/home/u");
        assert_eq!(dir(&[home]).as_deref(), Some("/home/u/.cache/stcvae"));
        assert_eq!(
            dir(&[home, ("XDG_CACHE_HOME", "/x")]).as_deref(),
            Some("/x/stcvae")
        );
        assert_eq!(
            dir(&[home, ("XDG_CACHE_HOME", "rel")]).as_deref(),
            Some("/home/u/.cache/stcvae")
        );
        assert_eq!(
            dir(&[home, ("XDG_CACHE_HOME", "")]).as_deref(),
            Some("/home/u/.cache/stcvae")
        );
        assert_eq!(
            dir(&[home, ("XDG_CACHE_HOME", "/x"), ("STCVAE_CACHE", "rel")]).as_deref(),
            Some("rel")
        );
        assert_eq!(
            dir(&[("STCVAE_CACHE", ""), home]).as_deref(),
            Some("/home/u/.cache/stcvae")
        );
        assert_eq!(dir(&[("HOME", "rel")]), None);
        assert_eq!(dir(&[]), None);
    }

    /// An unusable entry is removed before it is rebuilt, so that its space is free for
    /// the new one (on a full disk the damaged file stayed and was rebuilt every run); a
    /// folder in an entry's place is not an entry and stays.
    #[test]
    fn an_unusable_entry_is_removed_before_its_rebuild() {
        let d = tempfile::tempdir().unwrap();
        let entry = d.path().join(format!("grid-x-{CODE}.bin"));
        std::fs::write(&entry, b"damaged").unwrap();
        assert!(note_unusable_entry(&entry));
        assert!(!entry.exists());
        assert!(!note_unusable_entry(&entry));
        std::fs::create_dir(&entry).unwrap();
        assert!(!note_unusable_entry(&entry));
        assert!(entry.is_dir());
    }

    /// A build that took longer than `cached_from` seconds is written to its entry: with
    /// `cached_from` = −1 every build does (it takes ≥ 0 s), so the entry then holds the
    /// built bytes, and the next call reads them back instead of building (a build that
    /// would fail here). Only builds replacing an unusable entry were written otherwise,
    /// and a slow grid was rebuilt every run.
    #[test]
    fn a_slow_build_is_written_to_its_entry_and_read_back() {
        let d = tempfile::tempdir().unwrap();
        let entry = d.path().join(format!("grid-x-{CODE}.bin"));
        let built = bytes_entry(&entry, || Ok(b"built".to_vec())).unwrap();
        assert_eq!(built, b"built");
        assert_eq!(std::fs::read(&entry).unwrap(), b"built");
        let read = bytes_entry(&entry, || Err("built again".to_string())).unwrap();
        assert_eq!(read, b"built");
    }

    /// Writing this code's cache file of a stem removes that stem's files written by other
    /// code, and nothing else: not another mesh's or resolution's (one that only extends
    /// the stem, 640 after 64), nor files that merely look alike.
    #[test]
    fn stale_cache_files_of_the_stem_are_removed() {
        let d = tempfile::tempdir().unwrap();
        let other_code = if CODE == "0123456789abcdef" {
            "fedcba9876543210"
        } else {
            "0123456789abcdef"
        };
        let mine = format!("grid-00ab-64-{CODE}.bin");
        let stale = format!("grid-00ab-64-{other_code}.bin");
        let kept = [
            format!("grid-00ab-640-{other_code}.bin"),
            format!("grid-00cd-64-{other_code}.bin"),
            format!("cones-00ab-{other_code}.bin"),
            "grid-00ab-64.bin".to_string(),
            "grid-00ab-64-notes.bin".to_string(),
        ];
        for n in kept.iter().chain([&mine, &stale]) {
            std::fs::write(d.path().join(n), b"x").unwrap();
        }
        prune_stale(&d.path().join(&mine));
        let mut left: Vec<String> = std::fs::read_dir(d.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        let mut want: Vec<String> = kept.iter().chain([&mine]).cloned().collect();
        want.sort();
        assert_eq!(left, want);
    }

    /// Past the cap the entries used longest ago go, oldest first, until the rest fit; the
    /// one just written stays even when it alone is larger; files that are not entries
    /// are neither counted nor removed.
    #[test]
    fn the_cache_keeps_its_most_recently_used_entries() {
        let d = tempfile::tempdir().unwrap();
        let entry = |stem: &str, bytes: usize, age_s: u64| {
            let p = d.path().join(format!("{stem}-{CODE}.bin"));
            std::fs::write(&p, vec![0u8; bytes]).unwrap();
            let f = std::fs::File::options().write(true).open(&p).unwrap();
            f.set_modified(SystemTime::now() - Duration::from_secs(age_s))
                .unwrap();
            p
        };
        let oldest = entry("grid-0001-64", 400, 500);
        let old = entry("cones-0002", 300, 400);
        let recent = entry("grid-0003-128", 200, 300);
        let newest = entry("grid-0004-64", 100, 200);
        let other = d.path().join("notes.bin");
        std::fs::write(&other, vec![0u8; 5000]).unwrap();
        // 400 + 300 + 200 + 100 = 1000 bytes: a cap of 1000 removes nothing.
        trim(&newest, 1000);
        assert!(oldest.exists() && old.exists() && recent.exists() && newest.exists());
        // A cap of 650: the oldest (400) goes, leaving 600; the rest stay.
        trim(&newest, 650);
        assert!(!oldest.exists() && old.exists() && recent.exists() && newest.exists());
        // Touched, `old` becomes the most recently used: a cap of 450 now removes `recent`
        // (used longer ago), leaving old + newest = 400.
        super::touch(&old);
        trim(&newest, 450);
        assert!(old.exists() && !recent.exists() && newest.exists());
        // A cap below the kept entry alone removes every other entry, never the kept one.
        trim(&newest, 10);
        assert!(!old.exists() && newest.exists());
        assert!(other.exists(), "a file that is no cache entry was removed");
    }

    /// The entry just written counts toward the cap, though it is never removed itself: an
    /// older entry of 400 bytes beside a kept one of 500 makes 900 over a cap of 600, so
    /// the older goes. Counted without the kept entry (400, under the cap) it stayed, and
    /// the cache held up to the cap plus the newest entry (a fine mesh's grid: GBs).
    #[test]
    fn the_kept_entry_counts_toward_the_cap() {
        let d = tempfile::tempdir().unwrap();
        let old = d.path().join(format!("grid-0001-64-{CODE}.bin"));
        let kept = d.path().join(format!("grid-0002-64-{CODE}.bin"));
        std::fs::write(&old, vec![0u8; 400]).unwrap();
        std::fs::write(&kept, vec![0u8; 500]).unwrap();
        trim(&kept, 600);
        assert!(!old.exists() && kept.exists());
    }

    /// The key of what is cached for a mesh (its distance grid, its escape cones) holds
    /// which vertices form each face and in what order the faces are listed, not only
    /// where the vertices are: the cube with its top face cut along the other diagonal, or
    /// with two faces listed in each other's places, has the same positions and as many
    /// triangles, so another's grid (whose lists name triangles by index) or cones (one
    /// per triangle) pass every check of a read entry but the key; under one key the
    /// renders would use them.
    #[test]
    fn the_mesh_key_sees_the_faces_not_only_the_vertices() {
        let key = |m: crate::mesh::TriMesh| {
            super::mesh_hasher(&crate::geometry::Geometry::new(m), b"tag").finish()
        };
        let cube = || crate::mesh::cube(1.0);
        let k = key(cube());
        assert_eq!(k, key(cube()), "one mesh, one key");
        let mut recut = cube();
        // The face y = +h, [2, 6, 7] and [2, 7, 3], cut along 6–3 instead of 2–7.
        assert_eq!(recut.triangles[6], [2, 6, 7]);
        assert_eq!(recut.triangles[7], [2, 7, 3]);
        recut.triangles[6] = [2, 6, 3];
        recut.triangles[7] = [6, 7, 3];
        assert_ne!(k, key(recut), "the other diagonal");
        let mut listed = cube();
        listed.triangles.swap(0, 11);
        assert_ne!(k, key(listed), "the faces listed in another order");
        assert_ne!(k, key(crate::mesh::cube(1.5)), "other positions");
    }

    /// An entry that `read_or_build` reads back is marked as used: its modification time,
    /// by which `trim` evicts the entries used longest ago, becomes now. Here the entry's
    /// time is set 100,000 s in the past; after the read it must be later than 50,000 s
    /// ago. That midpoint leaves half a day of margin on both sides ("touched" is ~0 s
    /// ago, "not touched" 100,000 s ago), whatever the file system's timestamp resolution
    /// or the test's speed. Without the touch, a grid read on every run kept the time it
    /// was written and was the first evicted when the cache went over its cap.
    #[test]
    fn an_entry_read_back_is_marked_used() {
        let d = tempfile::tempdir().unwrap();
        let entry = d.path().join(format!("grid-x-{CODE}.bin"));
        std::fs::write(&entry, b"cached").unwrap();
        let long_ago = SystemTime::now() - Duration::from_secs(100_000);
        std::fs::File::options()
            .write(true)
            .open(&entry)
            .unwrap()
            .set_modified(long_ago)
            .unwrap();
        let read = bytes_entry(&entry, || Err("built instead of read".to_string())).unwrap();
        assert_eq!(read, b"cached");
        let modified = std::fs::metadata(&entry).unwrap().modified().unwrap();
        assert!(
            modified > long_ago + Duration::from_secs(50_000),
            "the entry read back kept its old modification time: {modified:?}"
        );
    }

    /// Writing an entry through `read_or_build` tidies the cache: the same stem's file
    /// written by other code (no build of this code can read it; a grid is up to tens of
    /// MB) is removed, another mesh's is kept. `prune_stale` alone is tested above; this
    /// checks that the one way entries are written calls it. `cached_from` = −1: every
    /// build (≥ 0 s) is written.
    #[test]
    fn writing_an_entry_removes_its_stems_files_of_other_code() {
        let d = tempfile::tempdir().unwrap();
        let other_code = if CODE == "0123456789abcdef" {
            "fedcba9876543210"
        } else {
            "0123456789abcdef"
        };
        let entry = d.path().join(format!("grid-00ab-64-{CODE}.bin"));
        let stale = d.path().join(format!("grid-00ab-64-{other_code}.bin"));
        let other_mesh = d.path().join(format!("grid-00cd-64-{other_code}.bin"));
        std::fs::write(&stale, b"old code").unwrap();
        std::fs::write(&other_mesh, b"another mesh").unwrap();
        let built = bytes_entry(&entry, || Ok(b"built".to_vec())).unwrap();
        assert_eq!(built, b"built");
        assert_eq!(std::fs::read(&entry).unwrap(), b"built");
        assert!(
            !stale.exists(),
            "the stem's file of other code stayed after this code's entry was written"
        );
        assert!(other_mesh.exists(), "another mesh's file was removed");
    }
}
