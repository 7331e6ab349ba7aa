//! Stored PT reference pairs for `stcvae bench render --pt-cache DIR`.
//!
//! At high density PT is almost all of the bench's time (k = 8, 16,386 spp: ~27 of 31
//! minutes), while what changes between runs when models or ST-CVAE settings are compared
//! is ST-CVAE alone. A PT pair depends only on the scene (its hash covers the ladder's
//! σ_t, the size and every render setting), the spp, the device (on a GPU with its
//! `STCVAE_GPU_*` kernel settings) and the binary (a rebuilt renderer may render PT
//! differently), which name the file; they are checked again on reading.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use render_gpu::hash::Fnv64;
use render_gpu::image_io::RgbImage;
use render_gpu::integrator::PathStats;
use serde::{Deserialize, Serialize};

use crate::experiment::measure::Pair;

/// Bumped whenever the stored fields or the meaning of a pair change (2: the checksum).
const VERSION: u32 = 2;

#[derive(Serialize, Deserialize)]
struct Stored {
    version: u32,
    width: usize,
    height: usize,
    mean: Vec<[f32; 3]>,
    var: Vec<[f64; 3]>,
    seconds: f64,
    stats: PathStats,
    work: Vec<f32>,
    spp: u32,
    /// Hex: JSON numbers lose u64 precision in some readers.
    hash: String,
    /// [`identity`] of the run that stored it.
    identity: String,
    /// Unix time of the run that measured it (its timing is that run's).
    measured_unix: u64,
    /// [`checksum_of`] the rest.
    checksum: String,
}

/// Fnv64 of the stored JSON with an empty checksum, in hex. A pair's pixels pass every
/// range check when one of their digits is changed: a bit flipped on disk (one digit of a
/// pixel's mean) turned the bias RMSE from 0 into 0.08 without a word. The JSON is written
/// and read back by serde_json alone, whose output of a value it parsed is the same text
/// because floats parse exactly with its `float_roundtrip` feature (the workspace's
/// Cargo.toml): without it a 17-digit f64 could read back one ulp off, and the pair as
/// damaged.
fn checksum_of(s: &Stored) -> Result<String> {
    debug_assert!(s.checksum.is_empty());
    let mut h = Fnv64::new();
    h.write(&serde_json::to_vec(s)?);
    Ok(format!("{:016x}", h.finish()))
}

/// What a stored pair depends on beyond the scene and spp: the device (`device`: the
/// adapter, or the CPU integrators' thread count), the CPU's model, on a GPU the
/// `STCVAE_GPU_*` settings, and this binary, so that a rebuilt renderer (say, a fix to PT)
/// never reuses an image it would not render.
pub fn identity(device: &str) -> Result<String> {
    let mut s = device.to_string();
    // The CPU's model is the host's too when a GPU renders; a CPU device names it already.
    if let Some(m) = crate::device::cpu_model()
        && !s.contains(&m)
    {
        s += " / ";
        s += &m;
    }
    // The GPU kernels' settings from the environment (workgroup size, stack, the staged
    // render, profiling) change a GPU's PT time: a pair timed under one must not supply
    // the speed-up of a run under another.
    if s.starts_with("gpu") {
        let mut vars: Vec<String> = std::env::vars_os()
            .filter_map(|(k, v)| {
                let k = k.to_str()?;
                k.starts_with("STCVAE_GPU_")
                    .then(|| format!("{k}={}", v.to_string_lossy()))
            })
            .collect();
        vars.sort();
        for v in vars {
            s += " / ";
            s += &v;
        }
    }
    let exe = std::env::current_exe().context("cannot locate this binary")?;
    let bytes = std::fs::read(&exe).with_context(|| format!("cannot read {}", exe.display()))?;
    let mut h = Fnv64::new();
    h.write(&bytes);
    Ok(format!("{s} / binary {:016x}", h.finish()))
}

/// The file of the PT pair for a scene hash, spp and [`identity`]. Another format
/// version or identity is another name, so it is a miss, not an error.
pub fn path(dir: &Path, k: f64, hash: u64, spp: u32, identity: &str) -> PathBuf {
    let mut h = Fnv64::new();
    h.write(identity.as_bytes());
    dir.join(format!(
        "pt-v{VERSION}-k{k}-{spp}spp-{:08x}-{hash:016x}.json",
        h.finish() as u32
    ))
}

/// Whether a pair can be stored and read back: it took some finite time, and its pixels
/// fit. Pixel means and variances are finite and ≥ 0 in any render (an edited file with a
/// negative variance gave a negative variance ratio, a mean of 1e39 an infinite bias), and
/// far below what squares or sums of them overflow (a variance of 1e308 printed "var ratio
/// inf ± NaN"): radiances are at most 1e12 (scene checks). Work counts are per pixel, or absent in a
/// pair stored before the GPU counted them (2026-12-04).
fn values_in_range(mean: &[[f32; 3]], var: &[[f64; 3]], work: &[f32], seconds: f64) -> bool {
    seconds.is_finite()
        && seconds > 0.0
        && var.len() == mean.len()
        && (work.is_empty() || work.len() == mean.len())
        && mean
            .iter()
            .flatten()
            .all(|v| v.is_finite() && (0.0..=1e15).contains(v))
        && var.iter().flatten().all(|v| (0.0..=1e30).contains(v))
        && work.iter().all(|v| v.is_finite() && *v >= 0.0)
}

/// A stored pair that cannot be used (damaged, edited, or not a pair at all): the bench
/// renders PT again and replaces it, with a note, as a cache does; it stopped the bench,
/// asking for the file to be deleted by hand. Errors reading the file stay errors.
#[derive(Debug)]
pub struct Damaged(String);

impl std::fmt::Display for Damaged {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Damaged {}

/// Whether `e` is [`Damaged`]'s.
pub fn is_damaged(e: &anyhow::Error) -> bool {
    e.downcast_ref::<Damaged>().is_some()
}

/// The stored pair and the Unix time it was measured at, if `file` exists; a [`Damaged`]
/// error where it cannot be used.
pub fn load(
    file: &Path,
    hash: u64,
    spp: u32,
    size: (u32, u32),
    identity: &str,
) -> Result<Option<(Pair, u64)>> {
    // A named pipe here blocked the bench and a link to /dev/zero read until memory ran out.
    let bytes = match scatter_sim::output::check_input(file).and_then(|()| std::fs::read(file)) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", file.display())),
    };
    let mut s: Stored = serde_json::from_slice(&bytes)
        .map_err(|e| Damaged(format!("{}: not a stored PT pair ({e})", file.display())))?;
    let sum = std::mem::take(&mut s.checksum);
    if checksum_of(&s)? != sum {
        return Err(Damaged(format!(
            "{}: damaged (its checksum does not match its contents)",
            file.display()
        ))
        .into());
    }
    let n = s.width.checked_mul(s.height);
    if s.version != VERSION
        || s.hash != format!("{hash:016x}")
        || s.spp != spp
        || s.identity != identity
        || (s.width, s.height) != (size.0 as usize, size.1 as usize)
        || n != Some(s.mean.len())
        || !values_in_range(&s.mean, &s.var, &s.work, s.seconds)
    {
        return Err(Damaged(format!(
            "{}: stored for another version, scene, spp, size, device or binary, or damaged",
            file.display()
        ))
        .into());
    }
    let pair = Pair {
        mean: RgbImage {
            width: s.width,
            height: s.height,
            pixels: s.mean,
        },
        var: s.var,
        seconds: s.seconds,
        stats: s.stats,
        work: s.work,
        spp: s.spp,
        hash,
        // Not stored: the caller's scene, whose hash the file's name and contents match,
        // gives it.
        view: None,
    };
    Ok(Some((pair, s.measured_unix)))
}

/// Seconds since the Unix epoch (0 if the clock is before it).
fn unix_now() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// How long ago a stored pair was measured, in seconds, minutes or hours as fits (a pair
/// of a few minutes read "0.0 h").
pub fn age(measured_unix: u64) -> String {
    let s = unix_now().saturating_sub(measured_unix);
    match s {
        0..120 => crate::progress::count(s, "second"),
        120..7200 => format!("{} minutes", s / 60),
        _ => format!("{:.1} h", s as f64 / 3600.0),
    }
}

/// Stores `pair` in `file` (written whole or not at all). A pair that `load` would refuse
/// (a non-finite value, which JSON cannot hold, or one beyond the ranges of
/// `values_in_range`) is not stored and `false` says so, so no file of ours reads as
/// damaged.
pub fn store(file: &Path, pair: &Pair, identity: &str) -> Result<bool> {
    if !values_in_range(&pair.mean.pixels, &pair.var, &pair.work, pair.seconds) {
        return Ok(false);
    }
    let mut s = Stored {
        version: VERSION,
        width: pair.mean.width,
        height: pair.mean.height,
        mean: pair.mean.pixels.clone(),
        var: pair.var.clone(),
        seconds: pair.seconds,
        stats: pair.stats,
        work: pair.work.clone(),
        spp: pair.spp,
        hash: format!("{:016x}", pair.hash),
        identity: identity.to_string(),
        measured_unix: unix_now(),
        checksum: String::new(),
    };
    s.checksum = checksum_of(&s)?;
    scatter_sim::output::write_atomic(file, &serde_json::to_vec(&s)?)
        .with_context(|| format!("cannot write {}", file.display()))?;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stored pair that is a named pipe or a device is refused by name, not waited on or
    /// read without end (a FIFO blocked the bench; /dev/zero filled memory).
    #[cfg(unix)]
    #[test]
    fn a_pair_that_is_no_file_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let (fifo, zero) = (d.path().join("p.json"), d.path().join("z.json"));
        let ok = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(ok.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
        std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
        for (f, what) in [(&fifo, "named pipe"), (&zero, "device")] {
            let Err(e) = load(f, 1, 2, (3, 2), "x") else {
                panic!("{} was read", f.display());
            };
            let e = format!("{e:#}");
            assert!(e.contains(what), "{e}");
        }
    }

    fn pair(hash: u64) -> Pair {
        let mut mean = RgbImage::new(3, 2);
        mean.pixels[4] = [0.25, 1.5, 3.0];
        Pair {
            mean,
            var: vec![[1e-3, 2e-3, 3e-3]; 6],
            seconds: 12.5,
            stats: PathStats {
                paths: 600,
                events: 7000,
                ..Default::default()
            },
            work: vec![1.0; 6],
            spp: 10,
            hash,
            view: None,
        }
    }

    #[test]
    fn a_stored_pair_reads_back_and_only_for_its_scene_and_spp() {
        let dir = tempfile::tempdir().unwrap();
        let p = pair(0xdead_beef_0123_4567);
        let id = identity("cpu (2 threads)").unwrap();
        let f = path(dir.path(), 8.0, p.hash, p.spp, &id);
        assert_ne!(f, path(dir.path(), 8.0, p.hash, p.spp, "gpu: other"));
        assert!(load(&f, p.hash, p.spp, (3, 2), &id).unwrap().is_none());
        assert!(store(&f, &p, &id).unwrap());
        let (q, when) = load(&f, p.hash, p.spp, (3, 2), &id).unwrap().unwrap();
        assert!(when > 0);
        assert_eq!(q.mean, p.mean);
        assert_eq!(q.var, p.var);
        assert_eq!(q.stats, p.stats);
        assert_eq!((q.seconds, q.spp, q.hash), (p.seconds, p.spp, p.hash));
        // Another scene, spp or identity under the same name (a renamed file) is refused
        // by name.
        for (h, spp, i) in [
            (p.hash ^ 1, p.spp, id.as_str()),
            (p.hash, p.spp + 3, id.as_str()),
            (p.hash, p.spp, "gpu: other"),
        ] {
            let err = load(&f, h, spp, (3, 2), i)
                .err()
                .expect("refused")
                .to_string();
            assert!(err.contains(f.to_str().unwrap()), "{err}");
        }
        // Edited values the report would print as inf, NaN or for another image size: a
        // variance of 1e308 (finite, but its ratio overflowed), a 2×3 image for a 3×2
        // bench, a negative work count.
        let text = std::fs::read_to_string(&f).unwrap();
        let stored: serde_json::Value = serde_json::from_str(&text).unwrap();
        // An edit with its checksum made again, so that the range checks are what refuse it.
        let sealed = |v: &serde_json::Value| {
            let mut s: Stored = serde_json::from_value(v.clone()).unwrap();
            s.checksum = String::new();
            s.checksum = checksum_of(&s).unwrap();
            serde_json::to_string(&s).unwrap()
        };
        // One digit of a pixel changed, within every range (a bit flipped on disk): the
        // checksum refuses it; sealed again, it would be read.
        let mut v = stored.clone();
        v["mean"][4][1] = 1.75.into();
        std::fs::write(&f, v.to_string()).unwrap();
        let err = load(&f, p.hash, p.spp, (3, 2), &id).err().expect("refused");
        assert!(is_damaged(&err), "{err:#}");
        assert!(
            format!("{err:#}").contains("damaged (its checksum"),
            "{err:#}"
        );
        std::fs::write(&f, sealed(&v)).unwrap();
        assert!(load(&f, p.hash, p.spp, (3, 2), &id).is_ok());
        type Edit = fn(&mut serde_json::Value);
        let edits: [Edit; 5] = [
            |v| v["var"][0][0] = 1e308.into(),
            |v| {
                v["width"] = 2.into();
                v["height"] = 3.into();
            },
            |v| v["work"][5] = (-1.0).into(),
            // Another format version, sealed.
            |v| v["version"] = (VERSION + 1).into(),
            // 5 pixels for a 3×2 image, every list as long: only width × height refuses it.
            |v| {
                for k in ["mean", "var", "work"] {
                    v[k].as_array_mut().unwrap().pop();
                }
            },
        ];
        for (i, edit) in edits.into_iter().enumerate() {
            let mut v = stored.clone();
            edit(&mut v);
            std::fs::write(&f, sealed(&v)).unwrap();
            let err = load(&f, p.hash, p.spp, (3, 2), &id).err().expect("refused");
            assert!(is_damaged(&err), "edit {i}: {err:#}");
        }
        std::fs::write(&f, stored.to_string()).unwrap();
        assert!(load(&f, p.hash, p.spp, (3, 2), &id).is_ok());
        // A pair without a per-pixel work map (a GPU's, stored before the kernels counted
        // one) reads back as stored (it was refused as damaged, failing every second GPU
        // bench).
        let gpu = Pair {
            work: Vec::new(),
            ..pair(p.hash)
        };
        assert!(store(&f, &gpu, &id).unwrap());
        let (q, _) = load(&f, p.hash, p.spp, (3, 2), &id).unwrap().unwrap();
        assert!(q.work.is_empty());
        std::fs::write(&f, b"{\"version\": 1").unwrap();
        let err = format!(
            "{:#}",
            load(&f, p.hash, p.spp, (3, 2), &id).err().expect("refused")
        );
        assert!(err.contains("not a stored PT pair"), "{err}");
        // A scene hash with leading zero digits reads back (named and stored with 16).
        let z = pair(0x00ab_cdef_0123_4567);
        let fz = path(dir.path(), 8.0, z.hash, z.spp, &id);
        assert!(store(&fz, &z, &id).unwrap());
        assert!(load(&fz, z.hash, z.spp, (3, 2), &id).unwrap().is_some());
    }

    /// A pair's age in seconds, minutes up to two hours, then hours; each figure holds if
    /// the clock ticks a second during the test.
    #[test]
    fn a_pairs_age_reads_in_seconds_minutes_or_hours() {
        let now = unix_now();
        assert_eq!(age(u64::MAX), "0 seconds"); // measured "in the future": 0
        assert_eq!(age(now - 300), "5 minutes");
        assert_eq!(age(now - 3600), "60 minutes");
        assert_eq!(age(now - 3 * 3600), "3.0 h"); // 10,800 s over 3,600
    }

    /// A stored pair's identity names the host's CPU model once: a GPU's after its adapter
    /// (PT's time on a GPU depends on the host too: a pair timed on one host must not give
    /// the speed-up on another with the same adapter), a CPU's where its device words name
    /// it already. Where the OS reports no model there is nothing to name.
    #[test]
    fn the_identity_names_the_cpu_model_once() {
        let Some(m) = crate::device::cpu_model() else {
            eprintln!("skipped: the OS reports no CPU model here");
            return;
        };
        let gpu = identity("gpu: Adapter (Vulkan, DiscreteGpu)").unwrap();
        assert!(
            gpu.starts_with(&format!("gpu: Adapter (Vulkan, DiscreteGpu) / {m} / ")),
            "{gpu}"
        );
        let cpu = identity(&format!("cpu (2 threads, {m})")).unwrap();
        assert_eq!(cpu.matches(m.as_str()).count(), 1, "{cpu}");
    }

    #[test]
    fn a_pair_that_would_read_as_damaged_is_not_stored() {
        let dir = tempfile::tempdir().unwrap();
        type Edit = fn(&mut Pair);
        let edits: [Edit; 10] = [
            |p| p.mean.pixels[1][2] = f32::NAN,
            |p| p.mean.pixels[1][2] = 1e20,
            |p| p.var[3][0] = 1e31,
            |p| p.work.truncate(2),
            |p| p.seconds = f64::INFINITY,
            |p| p.seconds = 0.0,
            |p| p.var.truncate(5),
            |p| p.mean.pixels[1][2] = -0.5,
            |p| p.var[3][0] = -1e-3,
            // JSON would write it as null.
            |p| p.work[0] = f32::INFINITY,
        ];
        for (i, edit) in edits.into_iter().enumerate() {
            let mut p = pair(7);
            edit(&mut p);
            let f = path(dir.path(), 1.0, p.hash, p.spp, "cpu");
            assert!(!store(&f, &p, "cpu").unwrap(), "edit {i}");
            assert!(!f.exists(), "edit {i}");
        }
    }
}
