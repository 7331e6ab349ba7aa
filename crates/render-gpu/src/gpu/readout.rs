//! What comes back from the GPU: the counters, tallied into the path statistics, and
//! the path slots, poisoned before the render and read into the image, the variance
//! image and the work map after it.

use crate::error::RenderError;
use crate::image_io::RgbImage;
use crate::integrator::PathStats;
use crate::render::DispatchStats;

use super::bands::Band;
use super::context::GpuContext;
use super::kernels;
use super::resources::{Resources, read_back, slot};

/// Counter slot `k` (a lo/hi pair of u32 words) of the counters `c` read back.
pub(super) fn counter(c: &[u8], k: u64) -> u64 {
    let k = k as usize;
    let word = |i: usize| u32::from_le_bytes(c[4 * i..4 * i + 4].try_into().unwrap()) as u64;
    word(2 * k) | (word(2 * k + 1) << 32)
}

/// Adds the counters `c` of a submission that stands to the render's path statistics and
/// lane profile; invocations stopped by the adapter's loop limit (at `budget` bounces a
/// dispatch) are an error.
pub(super) fn tally(
    ctx: &GpuContext,
    c: &[u8],
    budget: u32,
    stats: &mut PathStats,
    dispatch: &mut DispatchStats,
) -> Result<(), RenderError> {
    let pair = |k: u64| counter(c, k);
    if let Some(lanes) = &mut dispatch.lanes {
        for (i, p) in lanes.phases.iter_mut().enumerate() {
            let k = super::resources::PATH_COUNTERS + 3 * i as u64;
            p.active += pair(k);
            p.capacity += pair(k + 1);
            p.passes += pair(k + 2);
        }
    }
    stats.add(&PathStats {
        paths: pair(slot::PATHS),
        events: pair(slot::EVENTS),
        steps: pair(slot::STEPS),
        leaks: pair(slot::LEAKS),
        capped: pair(slot::CAPPED),
        non_finite: pair(slot::NON_FINITE),
        exact_steps: pair(slot::EXACT),
        exact_events: pair(slot::EXACT_EVENTS),
    });
    if pair(slot::TRUNCATED) > 0 {
        let hint = if budget > 1 {
            format!("set STCVAE_GPU_BOUNCES below {budget}")
        } else {
            // One bounce's loops: exact walks (exact_tau; past MODEL_MAX_G every step is
            // exact, and only max_tau bounds a walk: a hint of exact_tau alone sent users
            // to a setting with no effect there), or hit tests over a coarse grid cell's
            // long triangle list (a fine mesh under a low grid_resolution).
            format!(
                "a single bounce exceeded it: lower render.exact_tau (render.max_tau where \
                 |medium.g| > {}: every step is exact there), raise render.grid_resolution",
                crate::scene::MODEL_MAX_G
            )
        };
        return Err(RenderError::Gpu(format!(
            "{} invocations were stopped by {}'s loop limit (lavapipe stops a shader \
             after 65,535 loop iterations); {hint} or use --device cpu",
            pair(slot::TRUNCATED),
            ctx.adapter.name,
        )));
    }
    Ok(())
}

/// Poisons the accumulation buffers: a pixel the kernel never wrote stays NaN and is
/// reported when the image is read back ([`SlotReadout::read`]) instead of passing as
/// black. A piece at a time, each submitted and
/// waited for: wgpu keeps every write's staging copy until a submission completes, and
/// written whole those copies doubled the host memory of the largest images (on
/// lavapipe, where the buffers are host memory too, ~190 bytes a pixel instead of ~95).
pub(super) fn poison(
    ctx: &GpuContext,
    accums: &[wgpu::Buffer],
    accum_bytes: &[u64],
) -> Result<(), RenderError> {
    const POISON_PIECE: u64 = 64 << 20;
    let largest = accum_bytes.iter().copied().max().unwrap_or(0);
    let nan = vec![0xffu8; POISON_PIECE.min(largest) as usize]; // all-ones f32 bits = NaN
    for (buf, &bytes) in accums.iter().zip(accum_bytes) {
        let mut at = 0;
        while at < bytes {
            let n = (bytes - at).min(POISON_PIECE);
            ctx.queue.write_buffer(buf, at, &nan[..n as usize]);
            ctx.queue.submit([]);
            super::resources::wait(ctx)?;
            at += n;
        }
    }
    Ok(())
}

/// How a render's path slots are laid out and how far it got: what reading them back
/// into images needs.
pub(super) struct SlotReadout {
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) lanes: u32,
    pub(super) slot_vec4s: u64,
    pub(super) path_nee_m: u32,
    pub(super) squares_kept: bool,
    /// Whole samples a pixel.
    pub(super) spp: u32,
    /// The bands that had begun a chunk a stop request dropped (see `render_gpu`).
    pub(super) dropped: Option<usize>,
    pub(super) seed: u64,
}

impl SlotReadout {
    /// The image, the variance image (where asked for and `spp` allows) and the work map
    /// from the bands' slots; a pixel unwritten, non-finite or short of `spp` finished
    /// samples is an error.
    pub(super) fn read(
        &self,
        ctx: &GpuContext,
        res: &Resources,
        bands: &[Band],
    ) -> Result<(RgbImage, Option<RgbImage>, Vec<f32>), RenderError> {
        let pixels = self.width as u64 * self.height as u64;
        let mut image = RgbImage::new(self.width as usize, self.height as usize);
        // Squared sums only where asked and where every channel has two samples, as the CPU
        // renderer gives its variance image (render::MIN_VARIANCE_SPP).
        let mut variance = (self.squares_kept && self.spp >= crate::render::MIN_VARIANCE_SPP)
            .then(|| RgbImage::new(self.width as usize, self.height as usize));
        // Per pixel the PT events + sphere steps a path, as the CPU renderer's `work`.
        let mut work = vec![0f32; pixels as usize];
        // Stopped in the first chunk: no sample is whole (slots of bands not yet reached still
        // hold the poison), so there is no image, as on the CPU.
        let bands = if self.spp == 0 { &[][..] } else { bands };
        let mut bad = 0usize;
        let mut short = 0usize;
        for band in bands {
            let bytes = read_back(ctx, &res.accums[band.index], band.bytes)?;
            // A Vec<u8> need not be aligned for f32s (cast_slice would panic): copied where not.
            let copied: Vec<f32>;
            let vals: &[f32] = match bytemuck::try_cast_slice(&bytes) {
                Ok(v) => v,
                Err(_) => {
                    copied = bytemuck::pod_collect_to_vec(&bytes);
                    &copied
                }
            };
            let committed = self.dropped.is_some_and(|started| band.index < started);
            let vectors = self.band_vectors(committed);
            let first = band.row0 as usize * self.width as usize;
            let count = band.rows as usize * self.width as usize;
            for (p, px) in image.pixels[first..first + count].iter_mut().enumerate() {
                let PixelSlots {
                    sum,
                    squares,
                    finished,
                    events,
                    paths,
                } = self.pixel_slots(vals, p, &vectors, variance.is_some());
                work[first + p] = (events / paths.max(1.0)) as f32;
                if !sum.iter().chain(&squares).all(|v| v.is_finite()) {
                    bad += 1;
                } else if finished != self.spp as f64 {
                    short += 1;
                }
                let pixel = (first + p) as u32;
                *px = crate::render::resolve_pixel(sum, self.spp, self.seed, pixel);
                if let Some(var) = &mut variance {
                    // The slots square the ×3 values they sum (kernels::acc_sq_vec4).
                    let squares = squares.map(|q| q / 9.0);
                    var.pixels[first + p] =
                        crate::render::pixel_variance(sum, squares, self.spp, self.seed, pixel);
                }
            }
        }
        if bad > 0 {
            return Err(RenderError::Gpu(format!(
                "{bad} of {pixels} pixels came back unwritten or non-finite from {}",
                ctx.adapter
            )));
        }
        if short > 0 {
            return Err(RenderError::Gpu(format!(
                "{short} of {pixels} pixels came back with a finished-sample count other than \
                 {} from {}",
                self.spp, ctx.adapter
            )));
        }
        Ok((image, variance, work))
    }

    /// Which vec4s of a band's slots hold its sums. A band whose chunk was dropped
    /// (`committed`) gives back the whole chunks' sums, rounded once to f32; the others their
    /// sums and what those rounded off.
    fn band_vectors(&self, committed: bool) -> BandVectors {
        // The work counts every visit, a dropped chunk's too: read from the live sums'
        // round-off vec4 in either case.
        let acc_lo = kernels::acc_lo_vec4(self.path_nee_m, self.squares_kept);
        if committed {
            BandVectors {
                acc: kernels::committed_vec4(self.path_nee_m, self.squares_kept),
                lo: None,
                squares: [Some(kernels::committed_sq_vec4(self.path_nee_m)), None],
                events: acc_lo,
            }
        } else {
            BandVectors {
                acc: kernels::ACC_VEC4,
                lo: Some(acc_lo),
                squares: [
                    Some(kernels::acc_sq_vec4(self.path_nee_m)),
                    Some(kernels::acc_sq_lo_vec4(self.path_nee_m)),
                ],
                events: acc_lo,
            }
        }
    }

    /// Pixel `p` of a band (`vals`, its slots' floats), summed over its lanes in f64;
    /// the squared sums only `with_squares`.
    fn pixel_slots(
        &self,
        vals: &[f32],
        p: usize,
        vectors: &BandVectors,
        with_squares: bool,
    ) -> PixelSlots {
        // xyz of vec4 `v` of `slot`, added to `to` in f64.
        let add = |to: &mut [f64; 3], slot: usize, v: u64| {
            let q = &vals[(slot + v as usize) * 4..][..3];
            for (t, q) in to.iter_mut().zip(q) {
                *t += *q as f64;
            }
        };
        let mut out = PixelSlots::default();
        for l in 0..self.lanes as usize {
            let slot = (p * self.lanes as usize + l) * self.slot_vec4s as usize;
            for v in std::iter::once(vectors.acc).chain(vectors.lo) {
                add(&mut out.sum, slot, v);
            }
            // The work counts every visit, a dropped chunk's too, so it is read per
            // path over every finished sample (ACC's count), not over the whole chunks'.
            out.events += vals[(slot + vectors.events as usize) * 4 + 3] as f64;
            out.paths += vals[(slot + kernels::ACC_VEC4 as usize) * 4 + 3] as f64;
            if with_squares {
                for v in vectors.squares.into_iter().flatten() {
                    add(&mut out.squares, slot, v);
                }
            }
            out.finished += vals[(slot + vectors.acc as usize) * 4 + 3] as f64;
        }
        out
    }
}

/// The vec4s of a slot that hold a band's sums ([`SlotReadout::band_vectors`]).
struct BandVectors {
    /// The sums, with the finished-sample count in w.
    acc: u64,
    /// What the sums rounded off, where kept.
    lo: Option<u64>,
    /// The squared sums and what they rounded off.
    squares: [Option<u64>; 2],
    /// The vec4 whose w counts the PT events and sphere steps.
    events: u64,
}

/// One pixel's slots summed over its lanes.
#[derive(Default)]
struct PixelSlots {
    sum: [f64; 3],
    squares: [f64; 3],
    /// Finished samples.
    finished: f64,
    /// PT events and sphere steps, and the paths that made them.
    events: f64,
    paths: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A counter is a pair of u32 words, low then high (the kernels carry into the high
    /// one: path.wgsl, add_counter_wide), read as one u64: a long render's events pass
    /// 2^32 (1024² pixels × 256 spp × ~20 PT events a path), and the low word alone would
    /// report them wrapped. Every render of the tests counts below 2^32, so only this
    /// reads a high word that is not 0.
    #[test]
    fn counters_read_both_words_of_their_pair() {
        let words: [u32; 6] = [u32::MAX, 0, 7, 3, 0, 1];
        let c: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        assert_eq!(counter(&c, 0), u32::MAX as u64);
        assert_eq!(counter(&c, 1), (3u64 << 32) | 7);
        assert_eq!(counter(&c, 2), 1u64 << 32);
    }
}
