//! Output files that appear whole or not at all.
//!
//! Everything stcvae writes goes to a temporary file beside the target and is renamed over
//! it only once complete, so an error, a Ctrl-C or a crash never leaves a half-written
//! file under the output name (the temporary is removed when dropped).

use std::io::{self, Write};
use std::path::Path;

mod atomic_file;
mod checks;
mod file_set;
mod set_marks;
mod temporaries;

pub use atomic_file::{AtomicFile, write_atomic};
pub use checks::{
    check_input, check_output_folder, check_output_path, check_replaceable, read_input_to_string,
};
pub use file_set::{Contents, write_atomic_set, write_atomic_set_streamed, write_atomic_set_then};
pub use set_marks::restore_killed_sets;
pub use temporaries::{Live, remove_live_temporaries, remove_stale_temporaries_of};

/// A note on stderr that cannot end the process: std's `eprintln!` panics where stderr is
/// a closed pipe (`stcvae … 2>&1 | less`, less quit), which the CLI takes as a request to
/// stop cleanly.
pub fn note(line: &str) {
    let _ = writeln!(io::stderr(), "{line}");
}

/// The folder `path` lies in: its parent, or "." for a bare file name (whose parent is
/// the empty path).
fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

#[cfg(test)]
mod tests {
    use std::fs;
    use std::io::{self, Write};
    use std::path::{Path, PathBuf};

    use super::atomic_file::*;
    use super::checks::*;
    use super::file_set::*;
    use super::set_marks::*;
    use super::temporaries::*;

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

    /// A set killed between its renames, in the state its own writer left: the tests above
    /// write the mark by hand, so what `write_set_with` notes in it (the inode it places
    /// at each name, which the sweep compares with the file there) was never read back.
    /// Here a.exr was placed and a.json not yet when the run died; the next sweep must put
    /// the earlier a.exr back, leaving the earlier set whole and nothing else.
    ///
    /// The kill is made from a rename hook: it keeps every file the folder holds at that
    /// moment as a hard link in a second temporary folder (same inodes, same file system),
    /// lets the rollback run (which a kill would skip), then moves the kept files back.
    #[cfg(unix)]
    #[test]
    fn a_set_killed_by_its_own_writer_is_put_back() {
        let d = tempfile::tempdir().unwrap();
        let frozen = tempfile::tempdir().unwrap();
        let (exr, json) = (d.path().join("a.exr"), d.path().join("a.json"));
        fs::write(&exr, b"old exr").unwrap();
        fs::write(&json, b"old json").unwrap();
        let set: [(&Path, &[u8]); 2] = [(&exr, b"new exr"), (&json, b"new json")];
        let names = || {
            let mut v: Vec<String> = fs::read_dir(d.path())
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            v.sort();
            v
        };
        let mut k = 0;
        let r = write_set_with(
            bytes_of(&set),
            |f| {
                k += 1;
                if k == 1 {
                    return f.persist();
                }
                // Killed before the second rename. Its temporary is left out (a killed
                // run's temporaries are another sweep's).
                let here: Vec<_> = fs::read_dir(d.path())
                    .unwrap()
                    .map(|e| e.unwrap().file_name())
                    .collect();
                for name in here {
                    if !name.to_string_lossy().ends_with(".partial") {
                        fs::hard_link(d.path().join(&name), frozen.path().join(&name)).unwrap();
                    }
                }
                Err(io::Error::other("killed"))
            },
            Previous::keep,
            || (),
        );
        assert!(r.is_err());
        // The killed run's files back in place, its process gone (no lock is held).
        let kept: Vec<_> = fs::read_dir(frozen.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        for name in kept {
            // (a.json is the same inode as the one there: rename leaves both names.)
            fs::rename(frozen.path().join(&name), d.path().join(&name)).unwrap();
        }
        assert_eq!(
            fs::read(&exr).unwrap(),
            b"new exr",
            "the killed state is a mix"
        );
        assert_eq!(fs::read(&json).unwrap(), b"old json");
        assert!(
            names()
                .iter()
                .any(|n| n.starts_with(".stcvae-set.") && n.ends_with(".renaming")),
            "no mark at the kill: {:?}",
            names()
        );
        restore_killed_sets(d.path());
        assert_eq!(fs::read(&exr).unwrap(), b"old exr");
        assert_eq!(fs::read(&json).unwrap(), b"old json");
        assert_eq!(names(), ["a.exr", "a.json"]);
    }

    /// A killed set's file whose name holds a space (`--out "my render"`) is put back like
    /// any other: its mark's line is "INODE NAME", split at the first space, so the name
    /// keeps its own spaces (the killed-set tests above use names without one).
    #[cfg(unix)]
    #[test]
    fn a_killed_sets_file_with_a_space_in_its_name_is_put_back() {
        use std::os::unix::fs::MetadataExt;
        let d = tempfile::tempdir().unwrap();
        let file = d.path().join("my render.exr");
        fs::write(&file, b"old").unwrap();
        let link = d
            .path()
            .join(format!("{}Kil123.stcvae-previous", temp_prefix(&file)));
        fs::hard_link(&file, &link).unwrap();
        let new = d.path().join("new");
        fs::write(&new, b"new").unwrap();
        fs::rename(&new, &file).unwrap();
        let ino = fs::metadata(&file).unwrap().ino();
        fs::write(
            d.path().join(".stcvae-set.Kil123.renaming"),
            format!("{ino} my render.exr\n"),
        )
        .unwrap();
        restore_killed_sets(d.path());
        assert_eq!(fs::read(&file).unwrap(), b"old");
        let left: Vec<String> = fs::read_dir(d.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(left, ["my render.exr"]);
    }

    /// A name over 64 bytes whose byte at offset 55 (the cut) falls inside a character (é
    /// is two bytes, at even offsets here, so byte 55 is the second half of one) has its
    /// temporaries' prefix cut at the character before, and is written, alone and in a
    /// set. (In `the_longest_names_are_written` the é's start at odd offsets: byte 55 is a
    /// boundary there, and the cut's step back was never taken.)
    #[test]
    fn a_long_name_cut_inside_a_character_is_written() {
        let d = tempfile::tempdir().unwrap();
        // 40 é's (80 bytes) + ".exr": 84 bytes, over the 64 kept whole.
        let name = format!("{}.exr", "é".repeat(40));
        assert!(!name.is_char_boundary(55));
        let p = d.path().join(&name);
        let prefix = temp_prefix(&p);
        // 27 é's (54 bytes, the boundary before byte 55), then the checksum.
        assert!(
            prefix.starts_with(&format!(".{}~", "é".repeat(27))),
            "{prefix}"
        );
        // "." + 54 + "~" + 8 hex digits + "." = 65 bytes, within the 66 of a 64-byte name.
        assert_eq!(prefix.len(), 65, "{prefix}");
        write_atomic(&p, b"x").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"x");
        // Replaced in a set: its predecessor kept as a link named by the same prefix.
        write_atomic_set(&[(p.as_path(), &b"y"[..])]).unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"y");
        assert_eq!(
            fs::read_dir(d.path()).unwrap().count(),
            1,
            "files left beside it"
        );
    }
}
