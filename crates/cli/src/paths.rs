//! Which file a path names, and outputs that would replace a command's own inputs.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};

/// A path as the summary lines show it: control characters escaped, as in the errors (an
/// `--out` holding a newline printed a summary over two lines).
pub(crate) use scatter_sim::ranges::printable_path as shown;

/// The file a path names, for comparing paths written differently (`./a.exr`, `a.exr`);
/// a path that does not exist yet is resolved through its nearest existing ancestor (so
/// `ck/m.stcvae` lies within `ck` while neither exists).
pub(crate) fn identity(p: &Path) -> PathBuf {
    if let Ok(c) = p.canonicalize() {
        return c;
    }
    for above in p.ancestors().skip(1) {
        let dir = if above.as_os_str().is_empty() {
            Path::new(".")
        } else {
            above
        };
        if let (Ok(mut c), Ok(rest)) = (dir.canonicalize(), p.strip_prefix(above)) {
            // The folders still to be made will be folders, so a `..` among them steps
            // back as it reads (`new/../a.exr` is `a.exr`, which the writer would replace).
            for part in rest.components() {
                match part {
                    std::path::Component::ParentDir => {
                        c.pop();
                    }
                    std::path::Component::CurDir => {}
                    other => c.push(other),
                }
            }
            return c;
        }
    }
    p.to_path_buf()
}

/// A path as a shell word, for the commands the messages and reports suggest: in single
/// quotes unless made of safe characters only, and after `./` where it would read as a
/// flag.
pub(crate) fn shell_word(p: &Path) -> String {
    let mut s = p.display().to_string();
    if s.starts_with('-') {
        s.insert_str(0, "./");
    }
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "/._-+,".contains(c))
    {
        s
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

/// Refuses an output that is one of the command's inputs (`inputs`: what each one is, a
/// flag or a config field, and its path). Outputs are written whole and renamed over their
/// target, so the input would be gone, and only after the work: checked before it.
pub(crate) fn check_not_input(flag: &str, out: &Path, inputs: &[(String, PathBuf)]) -> Result<()> {
    let o = identity(out);
    for (what, p) in inputs {
        if identity(p) == o {
            bail!(
                "{flag} {} is also {what}, which the output would replace: choose another name",
                out.display()
            );
        }
    }
    Ok(())
}

/// The extensions of the files the commands write and read, by what they hold.
pub(crate) const IMAGE_EXTS: [&str; 3] = ["exr", "png", "json"];
pub(crate) const CONFIG_EXTS: [&str; 2] = ["toml", "md"];
pub(crate) const MODEL_EXTS: [&str; 1] = ["stcvae"];
pub(crate) const DATASET_EXTS: [&str; 2] = ["bin", "csv"];

/// [`check_kind`] for a dataset output (`generate`, `merge`): not an image, config or
/// model name.
pub(crate) fn check_dataset_out(out: &Path, holds: &str) -> Result<()> {
    let not_datasets = [&IMAGE_EXTS[..], &CONFIG_EXTS, &MODEL_EXTS].concat();
    check_kind("--out", out, holds, &not_datasets)
}

/// Refuses an output named like a file of another kind (`exts`): `generate --out
/// models/default.stcvae` replaced the shipped model with a dataset, `train --out w.csv`
/// a CSV with a model, both without a word. `holds` says what the command writes.
pub(crate) fn check_kind(flag: &str, out: &Path, holds: &str, exts: &[&str]) -> Result<()> {
    check_not_stdout(flag, out)?;
    if let Some(ext) = out.extension().and_then(|e| e.to_str())
        && exts.iter().any(|x| ext.eq_ignore_ascii_case(x))
    {
        bail!(
            "{flag} {}: this writes {holds}, not a .{ext} file; choose another name",
            out.display()
        );
    }
    Ok(())
}

/// Refuses `-` as an output: many tools read it as standard output, and stcvae wrote a
/// file named `-` in the working folder. `./-` still names such a file.
pub(crate) fn check_not_stdout(flag: &str, out: &Path) -> Result<()> {
    if out.as_os_str() == "-" {
        bail!(
            "{flag} -: stcvae writes files, not standard output; give a file name (./- for a \
             file named -)"
        );
    }
    Ok(())
}

/// Refuses a dataset or CSV of `walks` rows that cannot fit in the free space of `out`'s
/// file system, before the work: such a run failed only when the disk filled, after hours
/// (`generate --samples 18446744073709551615` started with an ETA of 45,962,785 years,
/// and `sample` wrote 50 MB/s toward a full disk). The bound is the least a row can take
/// in the format, so no run that fits is refused; `lower` names what to lower.
pub(crate) fn check_room(out: &Path, walks: u64, lower: &str) -> Result<()> {
    let per_walk = scatter_sim::dataset::least_row_bytes(out);
    let need = walks.saturating_mul(per_walk);
    if let Some(free) = free_bytes(out)
        && need > free
    {
        bail!(
            "{}: {} need at least {} ({per_walk} bytes a walk at least), and its file system \
             has {} free: lower {lower}, or write elsewhere",
            out.display(),
            crate::progress::count(walks, "walk"),
            indicatif::HumanBytes(need),
            indicatif::HumanBytes(free)
        );
    }
    Ok(())
}

/// Bytes this user may still write on the file system that will hold `out` (its nearest
/// existing folder), where the OS says (Unix; None elsewhere or on error).
pub(crate) fn free_bytes(out: &Path) -> Option<u64> {
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        let dir = out
            .ancestors()
            .skip(1)
            .map(|a| {
                if a.as_os_str().is_empty() {
                    Path::new(".")
                } else {
                    a
                }
            })
            .find(|a| a.is_dir())?;
        let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
        let mut st = std::mem::MaybeUninit::<libc::statvfs>::uninit();
        // SAFETY: `c` is a NUL-terminated path and `st` a buffer statvfs fills on success.
        if unsafe { libc::statvfs(c.as_ptr(), st.as_mut_ptr()) } != 0 {
            return None;
        }
        // SAFETY: statvfs returned 0, so it filled `st`.
        let st = unsafe { st.assume_init() };
        // A file system that reports no sizes (a FUSE one without statfs, or one queried
        // by a user it does not serve) gives zeros: unknown, not full.
        if st.f_blocks == 0 || st.f_frsize == 0 {
            return None;
        }
        // fsblkcnt_t and c_ulong are 32 bits on some targets.
        #[allow(clippy::unnecessary_cast)]
        Some((st.f_bavail as u64).saturating_mul(st.f_frsize as u64))
    }
    #[cfg(not(unix))]
    {
        let _ = out;
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_output_naming_an_input_another_way_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.exr");
        std::fs::write(&input, b"x").unwrap();
        let inputs = [("--reference".to_string(), input.clone())];
        // The same file through a `.` component and through a link to its folder.
        let dotted = dir.path().join(".").join("in.exr");
        let e = check_not_input("--plot", &dotted, &inputs).unwrap_err();
        assert!(e.to_string().contains("is also --reference"), "{e}");
        #[cfg(unix)]
        {
            let link = dir.path().join("link");
            std::os::unix::fs::symlink(dir.path(), &link).unwrap();
            assert!(check_not_input("--plot", &link.join("in.exr"), &inputs).is_err());
        }
        // Another name, existing or not, passes; so does an input that does not exist.
        assert!(check_not_input("--plot", &dir.path().join("plot.png"), &inputs).is_ok());
        let missing = [("--config".to_string(), dir.path().join("nope.toml"))];
        assert!(check_not_input("--out", &input, &missing).is_ok());
    }

    /// A count whose bytes pass u64 needs more than any disk holds: the need saturates.
    /// 2^63 walks of 56 bytes (binary) or 26 (CSV) are 7·2^66 and 13·2^64 bytes, both 0
    /// modulo 2^64, so a wrapped product would need nothing and let the run start. (The
    /// command-line test's 2^64 − 1 walks wrap to just below 2^64 and are refused either
    /// way.) Unix only: elsewhere the free space is not read.
    #[cfg(unix)]
    #[test]
    fn a_need_past_u64_saturates() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["x.bin", "x.csv"] {
            let out = dir.path().join(name);
            if free_bytes(&out).is_none() {
                eprintln!("skipped: {} reports no sizes", dir.path().display());
                return;
            }
            let e = check_room(&out, 1 << 63, "--samples")
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("9223372036854775808 walks need at least 16.00 EiB"),
                "{e}"
            );
        }
    }

    /// The refusal's free space is the file system's (`free_bytes`), not the need again:
    /// u64::MAX walks need 16.00 EiB, far beyond any disk, and the figure after "has" must
    /// read back within a factor of 2 of what statvfs says just after (other writers may
    /// change it between the two reads, by far less than that on a disk with room).
    #[cfg(unix)]
    #[test]
    fn a_refusal_names_the_space_free() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("x.bin");
        let e = match check_room(&out, u64::MAX, "--samples") {
            Ok(()) => {
                // A file system that reports no sizes: nothing is refused there.
                assert!(free_bytes(&out).is_none());
                eprintln!("skipped: {} reports no sizes", dir.path().display());
                return;
            }
            Err(e) => e.to_string(),
        };
        let free = free_bytes(&out).unwrap() as f64;
        // indicatif's HumanBytes: "512 B", "93.12 GiB".
        let figure = e
            .split_once("its file system has ")
            .and_then(|(_, rest)| rest.split_once(" free"))
            .unwrap_or_else(|| panic!("{e}"))
            .0;
        let (number, unit) = figure.split_once(' ').unwrap_or_else(|| panic!("{e}"));
        let power = ["B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"]
            .iter()
            .position(|u| *u == unit)
            .unwrap_or_else(|| panic!("{e}"));
        let shown = number.parse::<f64>().unwrap() * 1024f64.powi(power as i32);
        assert!(
            shown <= 2.0 * free.max(1.0) && free <= 2.0 * shown.max(1.0),
            "{free} bytes free: {e}"
        );
    }

    /// Paths that do not exist yet resolve through their nearest existing ancestor, so a
    /// file within a folder still to be made lies within it (`train --out ck/m.stcvae`
    /// with checkpoint_dir = ck was missed: one side stayed relative).
    #[test]
    fn missing_paths_resolve_through_their_nearest_existing_ancestor() {
        let dir = tempfile::tempdir().unwrap();
        let real = dir.path().canonicalize().unwrap();
        let deep = dir.path().join("a").join("b").join("m.stcvae");
        assert_eq!(identity(&deep), real.join("a/b/m.stcvae"));
        assert!(identity(&deep).starts_with(identity(&dir.path().join("a"))));
        let dotted = dir.path().join("a").join(".").join("b").join("m.stcvae");
        assert_eq!(identity(&dotted), identity(&deep));
        // A `..` among the folders to be made steps back: `new/../in.exr` is `in.exr`
        // (merge replaced its input through it).
        let back = dir.path().join("new").join("..").join("in.exr");
        assert_eq!(identity(&back), real.join("in.exr"));
        let up = dir
            .path()
            .join("a")
            .join("b")
            .join("..")
            .join("..")
            .join("..");
        assert_eq!(
            identity(&up.join("x")),
            identity(&real.join("..").join("x"))
        );
    }
}
