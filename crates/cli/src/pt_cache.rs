//! Stored PT reference pairs for `stcvae bench render --pt-cache DIR`.
//!
//! At high density PT is almost all of the bench's time (k = 8, 16,386 spp: ~27 of 31
//! minutes), while what changes between runs when models or ST-CVAE settings are compared
//! is ST-CVAE alone. A PT pair depends only on the scene (its hash covers the ladder's
//! σ_t, the size and every render setting), the spp and the device, which name the file;
//! the stored hash and spp are checked again on reading.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use render_gpu::image_io::RgbImage;
use render_gpu::integrator::PathStats;
use serde::{Deserialize, Serialize};

use crate::experiment::measure::Pair;

/// Bumped whenever the stored fields or the meaning of a pair change.
const VERSION: u32 = 1;

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
    /// Unix time of the run that measured it (its timing is that run's).
    measured_unix: u64,
}

/// The file of the PT pair for a scene hash, spp and device (a short name: cpu or gpu
/// and a hash of the adapter or thread count).
pub fn path(dir: &Path, k: f64, hash: u64, spp: u32, device: &str) -> PathBuf {
    dir.join(format!("pt-k{k}-{spp}spp-{device}-{hash:016x}.json"))
}

/// The stored pair and the Unix time it was measured at, if `file` exists.
pub fn load(file: &Path, hash: u64, spp: u32) -> Result<Option<(Pair, u64)>> {
    let bytes = match std::fs::read(file) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", file.display())),
    };
    let s: Stored = serde_json::from_slice(&bytes).with_context(|| {
        format!(
            "{}: not a stored PT pair (delete it to render PT again)",
            file.display()
        )
    })?;
    let n = s.width.checked_mul(s.height);
    if s.version != VERSION
        || s.hash != format!("{hash:016x}")
        || s.spp != spp
        || n != Some(s.mean.len())
        || s.var.len() != s.mean.len()
        || !(s.seconds.is_finite() && s.seconds > 0.0)
    {
        bail!(
            "{}: stored for another version, scene, spp or size, or damaged (delete it to \
             render PT again)",
            file.display()
        );
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
    };
    Ok(Some((pair, s.measured_unix)))
}

/// Stores `pair` in `file` (written whole or not at all).
pub fn store(file: &Path, pair: &Pair) -> Result<()> {
    if let Some(dir) = file.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let s = Stored {
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
        measured_unix: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs()),
    };
    scatter_sim::output::write_atomic(file, &serde_json::to_vec(&s)?)
        .with_context(|| format!("cannot write {}", file.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

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
        }
    }

    #[test]
    fn a_stored_pair_reads_back_and_only_for_its_scene_and_spp() {
        let dir = tempfile::tempdir().unwrap();
        let p = pair(0xdead_beef_0123_4567);
        let f = path(dir.path(), 8.0, p.hash, p.spp, "cpu");
        assert!(load(&f, p.hash, p.spp).unwrap().is_none());
        store(&f, &p).unwrap();
        let (q, when) = load(&f, p.hash, p.spp).unwrap().unwrap();
        assert!(when > 0);
        assert_eq!(q.mean, p.mean);
        assert_eq!(q.var, p.var);
        assert_eq!(q.stats, p.stats);
        assert_eq!((q.seconds, q.spp, q.hash), (p.seconds, p.spp, p.hash));
        // Another scene or spp under the same name (a renamed file) is refused by name.
        for (h, spp) in [(p.hash ^ 1, p.spp), (p.hash, p.spp + 3)] {
            let err = load(&f, h, spp).err().expect("refused").to_string();
            assert!(err.contains(f.to_str().unwrap()), "{err}");
        }
        std::fs::write(&f, b"{\"version\": 1").unwrap();
        let err = format!("{:#}", load(&f, p.hash, p.spp).err().expect("refused"));
        assert!(err.contains("delete it"), "{err}");
    }
}
