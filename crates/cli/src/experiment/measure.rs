//! Renders for the experiments and the figures measured on them: time, paths/s, work per
//! path, the per-pixel noise from two seeds and the noise-corrected bias between two
//! integrators (the same estimator as `stcvae bench render`).

use std::path::Path;

use anyhow::{Result, bail};
use render_gpu::image_io::{RenderTag, RgbImage};
use render_gpu::integrator::{IntegratorKind, PathStats};
use render_gpu::render::{RenderOptions, RenderOutput};
use render_gpu::scene::SceneFile;

use super::Ctx;
use crate::render::prepare;

/// A render made of two seeds: their mean, the per-pixel variance of that mean
/// ((A₁ − A₂)²/4 per channel), time and statistics summed, the work map averaged.
pub struct Pair {
    pub mean: RgbImage,
    pub var: Vec<[f64; 3]>,
    pub seconds: f64,
    pub stats: PathStats,
    pub work: Vec<f32>,
    pub spp: u32,
    pub hash: u64,
    /// What the images show ([`render_gpu::setup::SceneData::view_hash`]); None for a
    /// pair read back from bench render's PT cache until its caller sets it.
    pub view: Option<u64>,
}

impl Pair {
    /// Whether any pixel's two renders differ: every comparison measures the object's
    /// pixels, found by their noise, and with none there is nothing to measure (0/0).
    pub fn has_noise(&self) -> bool {
        self.var.iter().flatten().any(|&v| v > 0.0)
    }

    /// The pair of two renders of the same scene with different seeds.
    pub fn from_halves(a: RenderOutput, b: RenderOutput, (hash, view): (u64, u64)) -> Self {
        let mut mean = RgbImage::new(a.image.width, a.image.height);
        let mut var = Vec::with_capacity(a.image.pixels.len());
        for ((m, x), y) in mean
            .pixels
            .iter_mut()
            .zip(&a.image.pixels)
            .zip(&b.image.pixels)
        {
            let mut v = [0f64; 3];
            for c in 0..3 {
                m[c] = 0.5 * (x[c] + y[c]);
                let d = (x[c] - y[c]) as f64;
                v[c] = 0.25 * d * d;
            }
            var.push(v);
        }
        let mut stats = a.stats;
        stats.add(&b.stats);
        let work = a
            .work
            .iter()
            .zip(b.work.iter().chain(std::iter::repeat(&0.0)))
            .map(|(x, y)| 0.5 * (x + y))
            .collect();
        Pair {
            mean,
            var,
            seconds: a.seconds + b.seconds,
            stats,
            work,
            spp: a.spp + b.spp,
            hash,
            view: Some(view),
        }
    }

    pub fn per_path(&self, n: u64) -> f64 {
        n as f64 / self.stats.paths.max(1) as f64
    }
    pub fn paths_per_second(&self) -> f64 {
        self.stats.paths as f64 / self.seconds.max(1e-9)
    }
}

/// Samples, seed and optional time budget (then spp is a cap) of one render.
pub fn opts(spp: u32, seed: u64, time_budget: Option<f64>) -> RenderOptions {
    RenderOptions {
        spp,
        seed,
        time_budget,
        variance: false,
    }
}

/// The image height an experiment renders at width `size`: the scene camera's aspect kept.
pub fn height_at(size: u32, camera: &render_gpu::scene::CameraDesc) -> u32 {
    let aspect = camera.height as f64 / camera.width as f64;
    ((size as f64 * aspect).round() as u32).max(1)
}

/// One render of `scene` edited by `edit`.
pub fn render_once(
    ctx: &Ctx,
    scene: &Path,
    (kind, nee): (IntegratorKind, bool),
    edit: &dyn Fn(&mut SceneFile),
    o: &RenderOptions,
) -> Result<(render_gpu::render::RenderOutput, (u64, u64))> {
    let size = ctx.budget.size();
    let p = prepare(scene, Some(kind), Some(nee), ctx.model.as_deref(), |f| {
        f.camera.height = height_at(size, &f.camera);
        f.camera.width = size;
        edit(f);
    })?;
    if let Some((key, w)) = crate::render::outside_training_warning(&p, scene) {
        let mut said = ctx.warnings.borrow_mut();
        if !said.iter().any(|(k, _)| *k == key) {
            eprintln!("warning: {w}");
            said.push((key, w));
        }
    }
    let set = p.settings();
    // Ctrl-C stops the render after its current pass; a cut-short render must not be
    // measured, so the experiment ends here without a report.
    let cam = &p.file.camera;
    let pb = crate::progress::render_bar(
        &format!("{}, seed {}", kind.name(), o.seed),
        cam.width as u64 * cam.height as u64,
        o,
    );
    // Experiments compare times: a hardware GPU gets the benches' untimed warm-up.
    let out = ctx
        .engine
        .warm_up(&p.data, &set, o.spp, o.seed, crate::interrupt::flag())
        .and_then(|()| {
            ctx.engine.render(
                &p.data,
                &set,
                o,
                &|done, _| pb.set_position(done),
                crate::interrupt::flag(),
            )
        });
    pb.finish_and_clear();
    let out = out?;
    if crate::interrupt::requested() {
        // (experiment::run says where the images saved so far are, if any were.)
        bail!("interrupted: no report written");
    }
    // The figures do not show leaks: said here (the torus knot's folded band went unseen).
    crate::render::leak_note(
        &out.stats,
        &format!("{} ({}, seed {}): ", scene.display(), kind.name(), o.seed),
    );
    Ok((out, (p.data.hash, p.data.view_hash)))
}

/// The two seeds of an integrator's pair. PT and ST-CVAE must not share them: a sample's
/// random stream depends on (seed, pixel, sample) alone, so with equal seeds both draw the
/// same jitter, hero channel and first flights (ST-CVAE's fallback events are PT events
/// on the same stream), their noises correlate, and the noise correction of the bias
/// subtracts noise that the difference does not contain (the bias and its bound read low).
pub fn pair_seeds(kind: IntegratorKind) -> [u64; 2] {
    match kind {
        IntegratorKind::Pt => [11, 12],
        IntegratorKind::Stcvae => [13, 14],
    }
}

/// Samples of each of a pair's two renders for `spp` in all: half, rounded up to a
/// multiple of 3 so that every pixel gives each hero channel the same number of samples
/// in both renders. (Each channel is the mean of its own samples at any spp, see
/// `render::resolve_pixel`; with equal counts a channel's noise is also the same in every
/// pixel and both seeds, which the noise estimates assume.)
pub fn half_spp(spp: u32) -> u32 {
    (spp / 2).max(1).div_ceil(3) * 3
}

/// Two seeds of [`half_spp`] samples each.
pub fn render_pair(
    ctx: &Ctx,
    scene: &Path,
    kind: IntegratorKind,
    edit: &dyn Fn(&mut SceneFile),
) -> Result<Pair> {
    // NEE as the config says (`nee`, default on).
    let nee = ctx.cfg.nee();
    let half = half_spp(ctx.budget.spp());
    let [s1, s2] = pair_seeds(kind);
    let (a, ids) = render_once(ctx, scene, (kind, nee), edit, &opts(half, s1, None))?;
    let (b, _) = render_once(ctx, scene, (kind, nee), edit, &opts(half, s2, None))?;
    let pair = Pair::from_halves(a, b, ids);
    // Every figure compares the object's pixels, found by their noise: with none (the
    // object out of view, unlit or black) the offsets came out 0/0 in figures.csv.
    if !pair.has_noise() {
        bail!(
            "{}: no pixel differs between the renders of seeds {s1} and {s2}: the object is \
             out of view, unlit or black, so there is nothing to measure (check the scene's \
             camera, lights and medium)",
            scene.display()
        );
    }
    Ok(pair)
}

/// 1 / (the 99th percentile of the luminance of the reference's pixels brighter than
/// 1/1,000 of its brightest): the exposure of the experiments' pictures, and the unit of
/// [`errors`]. A visible background above that floor counts (it cannot be told from the
/// object without the renders' noise), so where it fills most of the frame this is about
/// the object's 95th percentile; comparisons that have the noise use [`object_scale`].
pub fn scale_of(reference: &RgbImage) -> f64 {
    let mut l: Vec<f64> = reference.pixels.iter().map(|p| lum(*p)).collect();
    let max = l.iter().cloned().fold(0.0, f64::max);
    l.retain(|&v| v > 1e-3 * max);
    inverse_p99(l).unwrap_or(1.0)
}

/// 1 / the 99th percentile of `l` (None when `l` is empty).
fn inverse_p99(mut l: Vec<f64>) -> Option<f64> {
    l.sort_by(f64::total_cmp);
    let v = l.get((l.len() * 99 / 100).min(l.len().saturating_sub(1)))?;
    Some(1.0 / v.max(1e-12))
}

/// [`scale_of`] over the pixels where either render of a comparison has noise: the object
/// (the constant background would otherwise count as object pixels and lower the 99th
/// percentile).
fn object_scale(reference: &Pair, other: &Pair) -> f64 {
    let l: Vec<f64> = (0..reference.mean.pixels.len())
        .filter(|&i| noisy(reference, other, i))
        .map(|i| lum(reference.mean.pixels[i]))
        .collect();
    // A 99th percentile of 0 (a black object) falls back to the whole frame's scale.
    inverse_p99(l)
        .filter(|&s| s < 1e12)
        .unwrap_or_else(|| scale_of(&reference.mean))
}

/// Whether pixel `i` has noise in either render (in any channel): an object pixel.
fn noisy(a: &Pair, b: &Pair, i: usize) -> bool {
    (0..3).any(|c| a.var[i][c] + b.var[i][c] > 0.0)
}

pub fn lum(p: [f32; 3]) -> f64 {
    (p[0] + p[1] + p[2]) as f64 / 3.0
}

/// PT (reference) against another integrator at equal spp.
pub struct Comparison {
    /// Wall-time ratio reference / other.
    pub speedup: f64,
    /// Per-pixel variance ratio reference / other (Σ Var_ref / Σ Var_other over the pixels).
    pub var_ratio: f64,
    /// Its standard error by the delta method over pixels, whose two-seed variance
    /// estimates are independent: se(A/B) = √Σ_pixels(Σ_channels a − R·b)² / B. A pixel's
    /// channels are summed first because the CPU renderer gives a pixel's three channels
    /// one jitter (render.rs), which correlates them at edges; counted as independent,
    /// their correlation ρ understated the error by up to √(1 + 2ρ²). Heavy-tailed pixels
    /// (rare paths of large weight) make the ratio swing by more than the speed-ups differ
    /// between settings, so it is printed with the ratio.
    pub var_ratio_se: f64,
    /// Noise-corrected RMSE over the object's pixels (those with noise in either
    /// render): √max(0, mean (A − B)² − mean (Var_A + Var_B)), scaled. The two renders
    /// must be independent ([`pair_seeds`]).
    pub bias: f64,
    /// One-sided 95 % upper bound on that RMSE: the per-pixel terms Σ_channels (A − B)² −
    /// Var_A − Var_B are independent across pixels (a pixel's channels, which share the
    /// CPU's jitter, are one term), so their mean has standard error s/√n and bias² ≤
    /// max(mean, 0) + 1.645·s/√n with at least 95 % confidence (normal approximation over
    /// n ≈ 10³–10⁴ object pixels; heavy-tailed pixels make s itself noisy, so read bounds
    /// near the target with a second seed pair). The estimate's negative values are
    /// raised to 0 first: an unbiased pair lands below 0 half the time and below
    /// −1.645·s/√n one time in twenty, where the plain bound (then shown as n/a) had
    /// nothing to say. None where too few pixels carry a term (`MIN_BIAS_TERMS`).
    pub bias_upper95: Option<f64>,
    /// RMSE the two noises alone would give over the object, scaled.
    pub noise: f64,
    /// Per channel (R, G, B): the noise-corrected bias RMSE, scaled like `bias`; and the
    /// other image's total over the reference's (over the pixels with noise: the object),
    /// minus 1, with its standard error (delta method on the two sums' variances). A model that gets the number of events wrong
    /// shows up as a brightness offset in the channel with the most absorption.
    pub channel_bias: [f64; 3],
    pub channel_offset: [(f64, f64); 3],
    /// Mean of z² over the object's BLOCK×BLOCK-pixel blocks and channels ([`block_z`])
    /// whose noise estimate has at least [`MIN_BLOCK_DOF`] degrees of freedom, and how
    /// many there are. Each block's noise is itself estimated, so under noise alone its z
    /// is a t-variable with ν (Welch–Satterthwaite) degrees of freedom: E z² = ν/(ν−2)
    /// (32/30 for 16 pixels in two images) and Var z² = 2ν²(ν−1)/((ν−2)²(ν−4)), which
    /// `block_null` sums over the blocks counted.
    /// A model error is smooth over a few pixels, so a block sees it with 16× less
    /// noise than a pixel; a per-pixel bias RMSE is noisy in its own right (a single
    /// heavy-tailed pixel moves it), this is not.
    pub block_chi2: f64,
    pub blocks: usize,
    /// What `block_chi2` would be under noise alone: mean and standard deviation, from
    /// each block's estimated ν (a plug-in: ν̂ is itself noisy for blocks of few noisy
    /// pixels, so the spread is a lower bound there; and it takes a block's three channels
    /// as independent, which the CPU's shared jitter makes them only nearly, at edges).
    pub block_null: (f64, f64),
}

/// Side of the pixel blocks of [`block_z`].
pub const BLOCK: usize = 4;

/// Per BLOCK×BLOCK block (row-major, ⌈w/BLOCK⌉ per row) and channel: Σ(B − A) over
/// its pixels divided by √Σ(Var_A + Var_B), the difference in units of its own noise;
/// None where neither image has noise (the background) or where the noise estimate has
/// fewer than [`MIN_BLOCK_DOF`] degrees of freedom (a silhouette block of a few noisy
/// pixels), whose z is t-distributed with ~2 degrees of freedom: |z| > 3 under noise
/// alone one time in ten, so a map of them lit the object's outline as bias.
pub fn block_z(a: &Pair, b: &Pair) -> Vec<[Option<f64>; 3]> {
    block_stats(a, b)
        .into_iter()
        .map(|z| z.map(|z| z.and_then(|(z, dof)| (dof >= MIN_BLOCK_DOF).then_some(z))))
        .collect()
}

/// Fewest effective degrees of freedom of a block's noise estimate for its z to enter the
/// χ² ([`Comparison::block_chi2`]). Each pixel's variance is a one-degree estimate (two
/// seeds); a block whose noise comes from one or two pixels — an object's silhouette
/// among background pixels without noise — has z ~ t with ν ≈ 2, whose z² has no finite
/// mean: one such block read z ≈ 35 and lifted a k = 8 χ²/dof from ~1.1 to 4.56. With
/// ν ≥ 10, E z² = ν/(ν − 2) ≤ 1.25; a block of 16 object pixels has ν ≈ 32.
pub const MIN_BLOCK_DOF: f64 = 10.0;

/// [`block_z`] with each block's effective degrees of freedom: Welch–Satterthwaite's
/// (Σ σ²)² / Σ σ⁴ over its pixels' variances in both images, each one-degree estimate v
/// standing for σ² and v²/3 for σ⁴ (E v² = 3σ⁴): 3(Σ v)² / Σ v².
fn block_stats(a: &Pair, b: &Pair) -> Vec<[Option<(f64, f64)>; 3]> {
    let (w, h) = (a.mean.width, a.mean.height);
    let mut out = Vec::new();
    for by in (0..h).step_by(BLOCK) {
        for bx in (0..w).step_by(BLOCK) {
            let mut z = [None; 3];
            for (c, zc) in z.iter_mut().enumerate() {
                let (mut d, mut var, mut var2) = (0.0f64, 0.0f64, 0.0f64);
                for y in by..(by + BLOCK).min(h) {
                    for x in bx..(bx + BLOCK).min(w) {
                        let i = y * w + x;
                        d += (b.mean.pixels[i][c] - a.mean.pixels[i][c]) as f64;
                        var += a.var[i][c] + b.var[i][c];
                        var2 += a.var[i][c] * a.var[i][c] + b.var[i][c] * b.var[i][c];
                    }
                }
                if var > 0.0 {
                    *zc = Some((d / var.sqrt(), 3.0 * var * var / var2));
                }
            }
            out.push(z);
        }
    }
    out
}

impl Comparison {
    /// The other image's total over the reference's, minus 1, averaged over the channels,
    /// with the mean of the channels' standard errors: an upper bound on the mean's
    /// whatever the channels' correlation (they share paths, so they are correlated).
    pub fn offset(&self) -> (f64, f64) {
        let o = &self.channel_offset;
        (
            o.iter().map(|c| c.0).sum::<f64>() / 3.0,
            o.iter().map(|c| c.1).sum::<f64>() / 3.0,
        )
    }
}

/// The noise-corrected squared bias per object pixel-channel, unscaled, and its standard
/// error ([`Comparison::bias_upper95`]): the mean over the `object` pixels of e = Σ_c e_c,
/// e_c = d_c² − Var_A,c − Var_B,c, over 3, and the spread of those per-pixel e (the
/// background's are 0 and count in neither); with the sums of each channel's e_c, for
/// [`Comparison::channel_bias`]; and how many pixels' e are not 0.
fn bias_squared(reference: &Pair, other: &Pair, object: usize) -> (f64, f64, [f64; 3], usize) {
    let (mut sum2, mut channels, mut terms) = (0.0f64, [0.0f64; 3], 0);
    for i in 0..reference.mean.pixels.len() {
        let mut e = 0.0;
        for (c, sum) in channels.iter_mut().enumerate() {
            let d = (reference.mean.pixels[i][c] - other.mean.pixels[i][c]) as f64;
            let e_c = d * d - reference.var[i][c] - other.var[i][c];
            *sum += e_c;
            e += e_c;
        }
        sum2 += e * e;
        terms += usize::from(e != 0.0);
    }
    let n = object.max(1) as f64;
    let mean = channels.iter().sum::<f64>() / n;
    let se = ((sum2 / n - mean * mean).max(0.0) / (n - 1.0).max(1.0)).sqrt();
    (mean / 3.0, se / 3.0, channels, terms)
}

/// Fewest pixels with a term e ≠ 0 for [`Comparison::bias_upper95`]'s normal
/// approximation. A pixel lit in one of the four renders alone has e = 0 exactly (d² and
/// the half-split variance estimate are both x²/4), so sparse renders (a quick run without
/// NEE: 25 object pixels, each lit once) gave a spread of 0 and a bound of 0 beside a
/// noise RMSE of 1.57. Thirty is the usual floor for a mean's normal approximation.
pub const MIN_BIAS_TERMS: usize = 30;

/// How the reports name [`Comparison::bias_upper95`], and when it is left unresolved.
pub fn bias_bound_words() -> String {
    format!(
        "its one-sided 95 % bound, not resolved where fewer than {MIN_BIAS_TERMS} object \
         pixels carry a term, as in sparse renders"
    )
}

pub fn compare(reference: &Pair, other: &Pair) -> Comparison {
    let scale = object_scale(reference, other);
    // Pixel-channels of the object: the background is the same constant in both renders
    // and would only dilute the RMSEs by the fraction of the frame it covers.
    let object = (0..reference.mean.pixels.len())
        .filter(|&i| noisy(reference, other, i))
        .count();
    let n = (object.max(1) * 3) as f64;
    let (mut va, mut vb) = (0.0, 0.0);
    // Σ reference, Σ other, Σ Var_reference, Σ Var_other per channel.
    let mut sums = [[0f64; 4]; 3];
    for i in 0..reference.mean.pixels.len() {
        for (c, sum) in sums.iter_mut().enumerate() {
            // Totals over the pixels with any noise: the object (a background pixel is the
            // same constant in both and would only dilute the offset).
            if reference.var[i][c] + other.var[i][c] > 0.0 {
                sum[0] += reference.mean.pixels[i][c] as f64;
                sum[1] += other.mean.pixels[i][c] as f64;
                sum[2] += reference.var[i][c];
                sum[3] += other.var[i][c];
            }
            va += reference.var[i][c];
            vb += other.var[i][c];
        }
    }
    let blocks: Vec<(f64, f64)> = block_stats(reference, other)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|&(_, dof)| dof >= MIN_BLOCK_DOF)
        .collect();
    let zs: Vec<f64> = blocks.iter().map(|&(z, _)| z).collect();
    let nb = blocks.len().max(1) as f64;
    let null_mean = blocks.iter().map(|&(_, v)| v / (v - 2.0)).sum::<f64>() / nb;
    let null_var = blocks
        .iter()
        .map(|&(_, v)| 2.0 * v * v * (v - 1.0) / ((v - 2.0) * (v - 2.0) * (v - 4.0)))
        .sum::<f64>()
        / (nb * nb);
    let (mean_e, se, ch_e, terms) = bias_squared(reference, other, object);
    let var_ratio = va / vb.max(1e-300);
    let var_ratio_se = reference
        .var
        .iter()
        .zip(&other.var)
        .map(|(a, b)| (0..3).map(|c| a[c] - var_ratio * b[c]).sum::<f64>().powi(2))
        .sum::<f64>()
        .sqrt()
        / vb.max(1e-300);
    Comparison {
        speedup: reference.seconds / other.seconds.max(1e-9),
        var_ratio,
        var_ratio_se,
        bias: mean_e.max(0.0).sqrt() * scale,
        bias_upper95: (terms >= MIN_BIAS_TERMS)
            .then(|| (mean_e.max(0.0) + 1.645 * se).sqrt() * scale),
        noise: ((va + vb) / n).sqrt() * scale,
        block_chi2: zs.iter().map(|z| z * z).sum::<f64>() / zs.len().max(1) as f64,
        blocks: zs.len(),
        block_null: (null_mean, null_var.sqrt()),
        channel_bias: ch_e.map(|e| (e / (n / 3.0)).max(0.0).sqrt() * scale),
        channel_offset: sums.map(|[r, o, vr, vo]| {
            let r = r.max(1e-300);
            let ratio = o / r;
            (
                ratio - 1.0,
                (vo / (r * r) + ratio * ratio * vr / (r * r)).sqrt(),
            )
        }),
    }
}

/// RMSE and mean absolute error of `img` against `reference`, in the reference's scaled
/// units. RMSE is decided by a handful of firefly pixels where there are any; MAE is not.
pub fn errors(reference: &RgbImage, img: &RgbImage) -> (f64, f64) {
    let scale = scale_of(reference);
    let n = (reference.pixels.len() * 3) as f64;
    let (mut sq, mut abs) = (0.0, 0.0);
    for (a, b) in reference.pixels.iter().zip(&img.pixels) {
        for c in 0..3 {
            let d = (a[c] - b[c]) as f64;
            sq += d * d;
            abs += d.abs();
        }
    }
    ((sq / n).sqrt() * scale, abs / n * scale)
}

/// |A − B| × `gain`, per channel.
pub fn difference(a: &RgbImage, b: &RgbImage, gain: f32) -> RgbImage {
    let mut d = RgbImage::new(a.width, a.height);
    for ((o, x), y) in d.pixels.iter_mut().zip(&a.pixels).zip(&b.pixels) {
        for c in 0..3 {
            o[c] = (x[c] - y[c]).abs() * gain;
        }
    }
    d
}

/// Images side by side with a 2-pixel white gap (all the same height): white as bright
/// as their brightest pixel.
pub fn side_by_side(images: &[&RgbImage]) -> RgbImage {
    let white = images
        .iter()
        .flat_map(|i| i.pixels.iter().map(|p| lum(*p) as f32))
        .fold(0.0f32, f32::max)
        .max(1e-6);
    side_by_side_with(images, [white; 3])
}

/// [`side_by_side`] with the gap (and any space below a shorter image) in `fill`.
pub fn side_by_side_with(images: &[&RgbImage], fill: [f32; 3]) -> RgbImage {
    let gap = 2;
    let h = images.iter().map(|i| i.height).max().unwrap_or(1);
    let w: usize =
        images.iter().map(|i| i.width).sum::<usize>() + gap * images.len().saturating_sub(1);
    let mut out = RgbImage::new(w.max(1), h);
    for p in &mut out.pixels {
        *p = fill;
    }
    let mut x0 = 0;
    for img in images {
        for y in 0..img.height {
            for x in 0..img.width {
                out.pixels[y * out.width + x0 + x] = img.pixels[y * img.width + x];
            }
        }
        x0 += img.width + gap;
    }
    out
}

/// A per-pixel work map as a grey image: log(1 + n) / log(1 + max), so maps drawn with
/// the same `max` compare directly.
pub fn work_image(work: &[f32], width: usize, height: usize, max: f32) -> RgbImage {
    let mut img = RgbImage::new(width, height);
    let denom = (1.0 + max.max(1e-6)).ln();
    for (p, &n) in img.pixels.iter_mut().zip(work) {
        let v = (1.0 + n.max(0.0)).ln() / denom;
        *p = [v; 3];
    }
    img
}

/// Writes a render (NAME.exr, linear, tagged with its spp, scene and seeds, so that `merge` can
/// average it with other renders of the scene and knows its samples) and its PNG; returns
/// the PNG's name for the report.
pub fn save(
    ctx: &Ctx,
    name: &str,
    img: &RgbImage,
    (spp, (hash, view), seeds): (u32, (u64, Option<u64>), &[u64]),
    exposure: f32,
) -> Result<String> {
    crate::merge::write_image_set(
        &ctx.out.join(name),
        img,
        &RenderTag {
            spp: spp as u64,
            scene_hash: hash,
            seeds: seeds.to_vec(),
            partial: false,
            unknown_digests: Vec::new(),
            view_hash: view,
        },
        exposure,
        None,
    )?;
    ctx.saved_one()?;
    Ok(format!("{name}.png"))
}

/// Writes a picture made from renders (renders side by side, a difference or a work map)
/// with an untagged EXR: it is no render of the scene, and `merge` refuses it (tagged as
/// one, as it was until 2026-12-02, two work maps of a scene could be averaged as renders).
pub fn save_picture(ctx: &Ctx, name: &str, img: &RgbImage, exposure: f32) -> Result<String> {
    crate::merge::write_image_set_with(&ctx.out.join(name), img, None, exposure, None, None, &[])?;
    ctx.saved_one()?;
    Ok(format!("{name}.png"))
}

/// Writes a map as NAME.exr holding `data` (linear values a reader can take numbers from,
/// untagged) and NAME.png showing `display`, one set as every image; returns the PNG's
/// name. The work maps: counts per path in the EXR, their log scale in the PNG.
pub fn save_map(ctx: &Ctx, name: &str, data: &RgbImage, display: &RgbImage) -> Result<String> {
    let (exr, png) = (
        ctx.out.join(format!("{name}.exr")),
        ctx.out.join(format!("{name}.png")),
    );
    let exr_bytes = render_gpu::image_io::encode_untagged_exr(data)
        .map_err(|e| anyhow::anyhow!("{}: {e}", exr.display()))?;
    let png_bytes = render_gpu::image_io::encode_png_linear(display)
        .map_err(|e| anyhow::anyhow!("{}: {e}", png.display()))?;
    scatter_sim::output::write_atomic_set(&[(&exr, &exr_bytes), (&png, &png_bytes)])
        .map_err(|(path, e)| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
    ctx.saved_one()?;
    Ok(format!("{name}.png"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use render_gpu::integrator::PathStats;
    use scatter_sim::rng::WalkRng;

    const SIDE: usize = 64;

    /// A pair of two seeds' renders of the image `truth`, each pixel's half drawn
    /// N(truth, σ²) with σ = 0.1·truth (f64 normals from the walk RNG's f32 ones).
    fn pair(truth: &[[f32; 3]], seed: u64) -> Pair {
        pair_with(truth, seed, 0.1)
    }

    /// As [`pair`] with σ = `rel`·truth.
    fn pair_with(truth: &[[f32; 3]], seed: u64, rel: f32) -> Pair {
        pair_noise(truth, seed, rel, false)
    }

    /// As [`pair_with`], each pixel's channels drawn with one normal where `shared` (the
    /// CPU renderer's shared jitter at its extreme, correlation 1).
    fn pair_noise(truth: &[[f32; 3]], seed: u64, rel: f32, shared: bool) -> Pair {
        let mut rng = WalkRng::for_walk(seed, 0);
        let halves: Vec<RgbImage> = (0..2)
            .map(|_| {
                let mut img = RgbImage::new(SIDE, SIDE);
                for (p, t) in img.pixels.iter_mut().zip(truth) {
                    // (No draw where unshared: the other tests' numbers stay as they were.)
                    let one = shared.then(|| rng.standard_normal());
                    for c in 0..3 {
                        let z = one.unwrap_or_else(|| rng.standard_normal());
                        p[c] = t[c] * (1.0 + rel * z);
                    }
                }
                img
            })
            .collect();
        let [a, b]: [RgbImage; 2] = halves.try_into().ok().unwrap();
        pair_of(a, b)
    }

    /// The pair of two 1-spp renders `a` and `b`, each timed at 1 s.
    fn pair_of(a: RgbImage, b: RgbImage) -> Pair {
        let out = |image: RgbImage| RenderOutput {
            image,
            spp: 1,
            seconds: 1.0,
            compile_seconds: 0.0,
            stats: PathStats::default(),
            work: Vec::new(),
            dispatch: Default::default(),
            variance: None,
        };
        Pair::from_halves(out(a), out(b), (0, 0))
    }

    /// A smooth "object": brightness varying over the image, with a background of 0 in the
    /// outer eighth (no noise there, so it is left out of the block statistics).
    fn truth() -> Vec<[f32; 3]> {
        (0..SIDE * SIDE)
            .map(|i| {
                let (x, y) = ((i % SIDE) as f32, (i / SIDE) as f32);
                let edge = SIDE as f32 / 8.0;
                if x < edge || y < edge || x >= SIDE as f32 - edge || y >= SIDE as f32 - edge {
                    [0.0; 3]
                } else {
                    let v = 0.5 + 0.4 * (x / 9.0).sin() * (y / 13.0).cos();
                    [v, 0.8 * v, 0.6 * v]
                }
            })
            .collect()
    }

    /// Two unbiased renders: the block χ²/dof is a mean of n = 432 squared t-variables
    /// with ν = 32 degrees of freedom (each block's noise is the sum of 32 one-degree
    /// estimates, 16 pixels in two images, of nearly equal variance here): E t² = ν/(ν−2)
    /// ≈ 1.07 and Var t² = 2ν²(ν−1)/((ν−2)²(ν−4)) ≈ 2.5, so the mean has sd ≈ 0.076 and 4
    /// sd is 0.31. The per-channel offsets are z-scores of sums of independent normals:
    /// each within 4 of its standard error.
    #[test]
    fn unbiased_renders_look_like_noise() {
        let t = truth();
        let c = compare(&pair(&t, 1), &pair(&t, 2));
        assert_noise_chi2(&c);
        // The null `bench render` prints beside the χ²: E t² and the sd of the mean over
        // the blocks, from each block's own degrees of freedom. At ν = 32 they are 1.067
        // and √(2.52/432) = 0.076; estimated per block from its pixels' variances, ν
        // moves them a little (1.064 and 0.076 here), so 0.03 and 15 % are allowed. The
        // sd of one block's t² in place of the mean's (1.58) failed nothing before.
        let (null_mean, null_sd) = c.block_null;
        assert!(
            (null_mean - 32.0 / 30.0).abs() < 0.03 && (null_sd / 0.0764 - 1.0).abs() < 0.15,
            "null {:?}",
            c.block_null
        );
        for (o, se) in c.channel_offset {
            assert!(o.abs() < 4.0 * se, "offset {o} ± {se}");
        }
        // The bias estimate is noise-corrected: its square is within a few standard
        // errors of 0, and the 95 % bound is of the order of that error. Per
        // pixel-channel e = d² − Var_A − Var_B has sd ≈ √3·σ² (d² is 2σ⁴ in variance,
        // each half-split variance estimate σ⁴/2), so over n = 6,912 object
        // pixel-channels the bound is noise·√((z + 1.645)·√3/√n) with z the estimate's
        // own z-score: ≈ 0.19·noise at z = 0, and 0.5·noise only at z ≈ 10. A bound
        // without the 1/√n in its standard error would be ~1.7·noise.
        let bound = c.bias_upper95.expect("6,912 object pixel-channels");
        assert!(c.bias < bound && bound < 0.5 * c.noise);
    }

    /// Renders lit sparsely (each object pixel in one of the four halves alone, as a quick
    /// run without NEE left them) give every pixel e = 0: the bound is unresolved, not 0
    /// beside a noise of the size of the signal. Thirty such pixels with one lit in two
    /// halves of the other pair resolve it.
    #[test]
    fn sparse_renders_leave_the_bias_bound_unresolved() {
        let lit = |at: &[usize], v: f32| {
            let mut img = RgbImage::new(SIDE, SIDE);
            for &i in at {
                img.pixels[i] = [v, 0.5 * v, 0.25 * v];
            }
            img
        };
        let object: Vec<usize> = (0..100).map(|i| 40 * i + 3).collect();
        let pt = pair_of(lit(&object, 1.0), lit(&[], 1.0));
        let dark = pair_of(lit(&[], 1.0), lit(&[], 1.0));
        let c = compare(&pt, &dark);
        assert!(
            c.noise > 0.0 && c.bias_upper95.is_none(),
            "{:?}",
            c.bias_upper95
        );
        // Lit at 2 in both halves: d² = (1/2 − 2)² against the variance 1/4, e ≠ 0.
        for n in [29, 30] {
            let both = pair_of(lit(&object[..n], 2.0), lit(&object[..n], 2.0));
            let c = compare(&pt, &both);
            assert_eq!(c.bias_upper95.is_some(), n >= MIN_BIAS_TERMS, "{n}");
        }
    }

    /// Every object block counted, and their χ²/dof within 4 sd of noise alone (see
    /// `unbiased_renders_look_like_noise`).
    fn assert_noise_chi2(c: &Comparison) {
        assert_eq!(c.blocks, 3 * 12 * 12);
        assert!(
            (c.block_chi2 - 32.0 / 30.0).abs() < 0.31,
            "chi2/dof {} over {}",
            c.block_chi2,
            c.blocks
        );
    }

    /// A silhouette block: one pixel with noise (two seeds that happen to agree closely)
    /// among pixels without. Its z is huge (~10⁴ here) but its noise estimate has ~2
    /// degrees of freedom, so it stays out of the χ², which stays that of noise alone
    /// (bounds as in `unbiased_renders_look_like_noise`), and out of the z map.
    #[test]
    fn a_lone_noisy_pixel_stays_out_of_the_chi2() {
        let t = truth();
        let (mut a, mut b) = (pair(&t, 1), pair(&t, 2));
        // Pixel (1, 1) lies in the background (no noise): give it a tiny variance and a
        // difference of 1 between the two images.
        let i = SIDE + 1;
        a.mean.pixels[i] = [1.0; 3];
        a.var[i] = [1e-8; 3];
        b.mean.pixels[i] = [2.0; 3];
        b.var[i] = [1e-8; 3];
        let (z, dof) = block_stats(&a, &b)[0][0].expect("the block has noise");
        assert!(z > 1e3 && dof < MIN_BLOCK_DOF, "z {z}, dof {dof}");
        assert_eq!(block_z(&a, &b)[0], [None; 3]);
        let c = compare(&a, &b);
        assert_noise_chi2(&c);
    }

    /// Renders with twice the noise: the variance ratio is 1/4, found within 4 of its
    /// standard error, and that error is about what 6,912 noisy pixel-channels (48×48
    /// object pixels × 3) give: each two-seed variance is a one-degree χ² (relative sd
    /// √2), so with equal variances the ratio's relative se would be √(2·2/n) = 2.4 %;
    /// this image's pixel variances vary (√(4Σσ⁴)/Σσ²), which makes it ~3.2 % (a review
    /// simulated 3.0–3.4 %; the test allows 1–4 %). Five seed pairs, so a wrong formula
    /// (e.g. without the square root, or over n instead of the sum of b) cannot pass by
    /// luck.
    #[test]
    fn the_variance_ratio_comes_with_its_standard_error() {
        let t = truth();
        for seed in 0..5 {
            let c = compare(&pair(&t, 10 + seed), &pair_with(&t, 20 + seed, 0.2));
            let rel = c.var_ratio_se / c.var_ratio;
            assert!((0.01..0.04).contains(&rel), "relative se {rel}");
            assert!(
                (c.var_ratio - 0.25).abs() < 4.0 * c.var_ratio_se,
                "var ratio {} ± {}",
                c.var_ratio,
                c.var_ratio_se
            );
        }
    }

    /// A 5 % darker third channel: the offset is found within 4 standard errors, the other
    /// channels stay within 4 of 0, and the blocks see it. A pixel's difference of means
    /// has variance 2·(0.1v)²/2 = 0.01v², so a block of 16 has z ≈ −0.05·16v/(0.4v) = −2
    /// and E z² ≈ 4 + 1.07 in that channel: χ²/dof ≈ (2·1.07 + 5.07)/3 ≈ 2.4 against
    /// 1.07 ± 0.08 for noise alone; 1.6 lies 7 sd above noise and far below 2.4.
    #[test]
    fn a_channel_offset_is_measured() {
        let t = truth();
        let darker: Vec<[f32; 3]> = t.iter().map(|p| [p[0], p[1], 0.95 * p[2]]).collect();
        let c = compare(&pair(&t, 1), &pair(&darker, 2));
        let (o, se) = c.channel_offset[2];
        assert!(
            (o + 0.05).abs() < 4.0 * se,
            "offset {o} ± {se}, expected -0.05"
        );
        for (o, se) in &c.channel_offset[..2] {
            assert!(o.abs() < 4.0 * se, "offset {o} ± {se}");
        }
        assert!(c.block_chi2 > 1.6, "chi2/dof {}", c.block_chi2);
    }

    /// `truth` with its third channel darker by the fraction `f`, and the squared bias
    /// that makes per object pixel-channel: the mean over the object's pixels of
    /// (f·v₃)²/3.
    fn third_channel_darker(truth: &[[f32; 3]], f: f64) -> (Vec<[f32; 3]>, f64) {
        let darker = truth
            .iter()
            .map(|p| [p[0], p[1], ((1.0 - f) * p[2] as f64) as f32])
            .collect();
        let object: Vec<&[f32; 3]> = truth.iter().filter(|p| p[0] > 0.0).collect();
        let b2 = object
            .iter()
            .map(|p| (f * p[2] as f64).powi(2) / 3.0)
            .sum::<f64>()
            / object.len() as f64;
        (darker, b2)
    }

    /// A known bias: the third channel 20 % darker, so the squared bias per object
    /// pixel-channel is the mean over the object's pixels of (0.2·0.6v)²/3, computed here
    /// from the truth. The estimate lies within 4 of its standard errors of it (a false
    /// alarm ~6e-5); the printed RMSE is its root in the comparison's scale, the bound is
    /// above it, and the third channel's own bias RMSE is √3 times the total's root (0.12v
    /// in that channel alone: its estimate has a relative error of ~1.2 %, so ±8 % is ~7
    /// of them), the others' near 0. A missing scale, a channel bias over n instead of
    /// n/3 (√3 off) or a wrong bias formula fail.
    #[test]
    fn a_known_bias_is_measured() {
        let t = truth();
        let (darker, truth_b2) = third_channel_darker(&t, 0.2);
        let (a, b) = (pair(&t, 3), pair(&darker, 4));
        let c = compare(&a, &b);
        let object = t.iter().filter(|p| p[0] > 0.0).count();
        let (est, se, ..) = bias_squared(&a, &b, object);
        assert!(
            (est - truth_b2).abs() < 4.0 * se,
            "bias² {est} ± {se}, truth {truth_b2}"
        );
        let scale = object_scale(&a, &b);
        assert!(
            (c.bias - est.sqrt() * scale).abs() < 1e-12 * c.bias.max(1.0),
            "{} against {}",
            c.bias,
            est.sqrt() * scale
        );
        assert!(
            c.bias_upper95.unwrap() > c.bias,
            "{c:?}",
            c = c.bias_upper95
        );
        let want = (3.0 * truth_b2).sqrt() * scale;
        assert!(
            (c.channel_bias[2] / want - 1.0).abs() < 0.08,
            "channel bias {} against {want}",
            c.channel_bias[2]
        );
        for cb in &c.channel_bias[..2] {
            assert!(*cb < 0.5 * want, "an unbiased channel's bias RMSE {cb}");
        }
    }

    /// The squared bias's standard error counts a pixel's channels as one term: with each
    /// pixel's three channels drawn from one normal (correlation 1, the CPU's shared jitter
    /// at its extreme), 200 unbiased seed pairs give estimates whose z = estimate / se has
    /// a spread near 1 (its own standard error ~0.05 over 200, so [0.8, 1.2] is 4 of
    /// them); counted as independent pixel-channels, the spread was 1.58 here (√3 for
    /// channels of equal brightness; this image's are 1 : 0.8 : 0.6).
    #[test]
    fn the_bias_standard_error_holds_for_correlated_channels() {
        let t = truth();
        let object = t.iter().filter(|p| p[0] > 0.0).count();
        let zs: Vec<f64> = (0..200)
            .map(|k| {
                let a = pair_noise(&t, 100 + 2 * k, 0.1, true);
                let b = pair_noise(&t, 101 + 2 * k, 0.1, true);
                let (est, se, ..) = bias_squared(&a, &b, object);
                est / se
            })
            .collect();
        let m = zs.iter().sum::<f64>() / zs.len() as f64;
        let sd = (zs.iter().map(|z| (z - m).powi(2)).sum::<f64>() / (zs.len() - 1) as f64).sqrt();
        eprintln!("spread of z {sd} (mean {m})");
        assert!((0.8..1.2).contains(&sd), "spread of z {sd} (mean {m})");
    }

    /// RMSE and MAE over every pixel-channel, in units where the reference's 99th
    /// percentile is 1, by hand: a reference of four pixels at 2 (the unit 1/2) and
    /// differences 0.1, −0.2, 0.3, −0.4 and 0.2 in five of its twelve channels give
    /// √(0.34/12)/2 = 0.08416 and (1.2/12)/2 = 0.05 (a mean over pixels, not channels,
    /// would be √3 and 3 times those).
    #[test]
    fn errors_by_hand() {
        let mut reference = RgbImage::new(2, 2);
        reference.pixels = vec![[2.0; 3]; 4];
        let mut img = reference.clone();
        img.pixels[0] = [2.1, 1.8, 2.3];
        img.pixels[2] = [1.6, 2.0, 2.0];
        img.pixels[3] = [2.0, 2.0, 2.2];
        let (rmse, mae) = errors(&reference, &img);
        let want = ((0.34f64 / 12.0).sqrt() / 2.0, 0.05);
        assert!(
            (rmse - want.0).abs() < 1e-6 && (mae - want.1).abs() < 1e-6,
            "({rmse}, {mae}) against {want:?}"
        );
    }

    /// The 95 % bound covers the bias it bounds: the third channel 10 % darker (the
    /// bias in the comparison's units from the truth, as in `a_known_bias_is_measured`),
    /// over 200 seed pairs. At the nominal 95 % about 190 ± 3 cover it (189 here), and
    /// 180 is 3.2 sd below. A bound that added the standard error of the squared bias to
    /// its root, not to the square (~100× too tight, and still above the estimate, which
    /// is all the other tests asked), covered 113.
    #[test]
    fn the_bias_bound_covers_a_known_bias() {
        let t = truth();
        let (darker, truth_b2) = third_channel_darker(&t, 0.1);
        let covered = (0..200u64)
            .filter(|k| {
                let (a, b) = (pair(&t, 1000 + 2 * k), pair(&darker, 1001 + 2 * k));
                let c = compare(&a, &b);
                c.bias_upper95.expect("6,912 object pixel-channels")
                    >= truth_b2.sqrt() * object_scale(&a, &b)
            })
            .count();
        assert!(
            covered >= 180,
            "the bound covered the bias in {covered} of 200"
        );
    }

    /// The channel offsets' standard errors are their spread: over 200 unbiased seed pairs
    /// the 600 z = offset / se (three independent channels a pair) have a standard
    /// deviation near 1 (its own ~0.03, so [0.85, 1.15] is 5 of them; 0.996 here). The
    /// other tests ask only |offset| < 4 se, which any se too large passes: one over r
    /// where it should be over r² (~30× too large) gave a spread of 0.033.
    #[test]
    fn the_channel_offsets_standard_errors_are_their_spread() {
        let t = truth();
        let zs: Vec<f64> = (0..200u64)
            .flat_map(|k| {
                let c = compare(&pair(&t, 3000 + 2 * k), &pair(&t, 3001 + 2 * k));
                c.channel_offset.map(|(o, se)| o / se)
            })
            .collect();
        let m = zs.iter().sum::<f64>() / zs.len() as f64;
        let sd = (zs.iter().map(|z| (z - m).powi(2)).sum::<f64>() / (zs.len() - 1) as f64).sqrt();
        assert!((0.85..1.15).contains(&sd), "spread of z {sd} (mean {m})");
    }

    /// A 2×2 image whose pixels' three channels are `v` (row-major).
    fn grey4(v: [f32; 4]) -> RgbImage {
        let mut img = RgbImage::new(2, 2);
        for (p, x) in img.pixels.iter_mut().zip(v.iter()) {
            *p = [*x; 3];
        }
        img
    }

    /// The noise RMSE is that of both renders' noises, by hand: three object pixels and a
    /// background pixel (0 in every half, no noise: left out). The reference's halves 1
    /// and 3 (mean 2, variance of the mean (3 − 1)²/4 = 1 per channel), the other's 4 and
    /// 0 (mean 2, variance 4); the unit is 1/2 (the object's 99th percentile is 2). So
    /// √((9·1 + 9·4)/9)/2 = √5/2 = 1.1180; the reference's noise alone would give 0.5,
    /// the other's alone 1.0, the background counted √(45/12)/2 = 0.968. Exact in binary
    /// up to the last rounding, so 1e-12.
    #[test]
    fn the_noise_rmse_is_that_of_both_renders() {
        let reference = pair_of(grey4([1.0, 1.0, 1.0, 0.0]), grey4([3.0, 3.0, 3.0, 0.0]));
        let other = pair_of(grey4([4.0, 4.0, 4.0, 0.0]), grey4([0.0; 4]));
        let c = compare(&reference, &other);
        let want = 5f64.sqrt() / 2.0;
        assert!(
            (c.noise - want).abs() < 1e-12,
            "noise {} against {want}",
            c.noise
        );
    }

    /// The object is every pixel with noise in either render: one ST-CVAE lights where PT
    /// leaves black (a leak) counts, with its whole error. Worked case: three pixels at 2
    /// in both (halves 1.75 and 2.25: variance of the mean 0.0625 per channel each, e_c =
    /// 0 − 2·0.0625 = −0.125), and a fourth that PT leaves at 0 in both halves while the
    /// other's halves are 3 and 1 (mean 2, variance 1: e_c = 2² − 0 − 1 = 3). Per channel
    /// Σe_c = 3·(−0.125) + 3 = 2.625 over 4 object pixels: bias² 0.65625, the unit 1/2
    /// (PT's 99th percentile over the four is 2), so bias √0.65625/2 = 0.40505 and noise
    /// √((9·0.0625 + 9·0.0625 + 3·1)/12)/2 = 0.29315. The object taken from PT's noise
    /// alone (three pixels) gives 0.46771 and 0.33850. Exact in binary up to the last
    /// rounding, so 1e-12.
    #[test]
    fn a_pixel_with_noise_in_the_other_render_alone_is_object() {
        let reference = pair_of(
            grey4([1.75, 1.75, 1.75, 0.0]),
            grey4([2.25, 2.25, 2.25, 0.0]),
        );
        let other = pair_of(
            grey4([1.75, 1.75, 1.75, 3.0]),
            grey4([2.25, 2.25, 2.25, 1.0]),
        );
        let c = compare(&reference, &other);
        let (bias, noise) = (0.65625f64.sqrt() / 2.0, (4.125f64 / 12.0).sqrt() / 2.0);
        assert!(
            (c.bias - bias).abs() < 1e-12 && (c.noise - noise).abs() < 1e-12,
            "bias {} and noise {} against {bias} and {noise}",
            c.bias,
            c.noise
        );
    }

    /// The exposure and the errors' unit is 1 / the 99th percentile of the pixels above
    /// 1/1,000 of the brightest, by hand: 200 pixels of luminance 1, 2, …, 200 and 800 of
    /// 0.1 (below 200/1,000 = 0.2: left out). Of the 200, index ⌊200·99/100⌋ = 198 holds
    /// 199, so 1/199 exactly; index ⌊199·99/100⌋ = 197 would give 1/198, the 800 dark
    /// pixels kept 1/191 (index 990 of 1,000), the 95th percentile 1/191.
    #[test]
    fn the_scale_is_the_99th_percentile_above_the_floor() {
        let mut img = RgbImage::new(1000, 1);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = if i < 200 {
                [(i + 1) as f32; 3]
            } else {
                [0.1; 3]
            };
        }
        let s = scale_of(&img);
        assert!((s - 1.0 / 199.0).abs() < 1e-15, "scale 1/{}", 1.0 / s);
    }

    /// The mean offset over the channels, and the mean of their standard errors (an upper
    /// bound on the mean's whatever the channels' correlation, as the absorption report
    /// says): offsets 3 %, −6 %, 0 % with errors 1 %, 2 %, 3 % give −1 % ± 2 %. As if
    /// independent, √(1 + 4 + 9)/3 = 1.247 % (lower); the errors' mean in place of the
    /// offsets', 2 %.
    #[test]
    fn the_mean_offset_and_its_error_bound() {
        let c = Comparison {
            speedup: 1.0,
            var_ratio: 1.0,
            var_ratio_se: 0.1,
            bias: 0.0,
            bias_upper95: None,
            noise: 0.01,
            channel_bias: [0.0; 3],
            channel_offset: [(0.03, 0.01), (-0.06, 0.02), (0.0, 0.03)],
            block_chi2: 1.0,
            blocks: 0,
            block_null: (1.0, 0.0),
        };
        let (o, se) = c.offset();
        assert!(
            (o + 0.01).abs() < 1e-12 && (se - 0.02).abs() < 1e-12,
            "offset {o} ± {se}, expected -0.01 ± 0.02"
        );
    }

    /// Where the reference is black on every object pixel (PT dark where the other render
    /// is lit: a leak), its 99th percentile there is 0, and the unit falls back to the
    /// whole frame's ([`scale_of`]): here a background pixel of 4, so 1/4 (exact). Worked
    /// case: PT 0 in three pixels (both halves) beside a background pixel of 4 without
    /// noise; the other's halves 1 and 3 there (mean 2, variance of the mean 1 per
    /// channel) and 4 in the background. Per object pixel-channel e = 2² − 0 − 1 = 3, so
    /// bias √3/4 = 0.4330 and noise √(9·1/9)/4 = 0.25. The inverse percentile of the black
    /// object is 1/1e-12, which is exactly 1e12 in f64: kept as the unit (a guard of ≤
    /// rather than <), it made the bias 1.7e12. Exact in binary up to the last rounding,
    /// so 1e-12.
    #[test]
    fn a_black_reference_object_takes_the_frames_scale() {
        let reference = pair_of(grey4([0.0, 0.0, 0.0, 4.0]), grey4([0.0, 0.0, 0.0, 4.0]));
        let other = pair_of(grey4([1.0, 1.0, 1.0, 4.0]), grey4([3.0, 3.0, 3.0, 4.0]));
        assert_eq!(object_scale(&reference, &other), 0.25);
        let c = compare(&reference, &other);
        let (bias, noise) = (3f64.sqrt() / 4.0, 0.25);
        assert!(
            (c.bias - bias).abs() < 1e-12 && (c.noise - noise).abs() < 1e-12,
            "bias {} and noise {} against {bias} and {noise}",
            c.bias,
            c.noise
        );
    }

    /// The exposure and the errors' unit take a pixel's luminance as the mean of its
    /// three channels: a red, a green and a blue pixel of 6 each read 2, so the scale is
    /// 1/2 (exact in binary). A luminance that counted the green channel twice in place of
    /// the blue read 2, 4 and 0 (scale 1/4); red alone 6, 0, 0 (1/6). The other tests use
    /// grey images, or compute the unit with the same function on both sides, which cannot
    /// tell them apart.
    #[test]
    fn the_scale_weighs_the_three_channels_alike() {
        let mut img = RgbImage::new(3, 1);
        img.pixels = vec![[6.0, 0.0, 0.0], [0.0, 6.0, 0.0], [0.0, 0.0, 6.0]];
        assert_eq!(scale_of(&img), 0.5);
        assert_eq!(lum([1.0, 2.0, 6.0]), 3.0);
    }

    /// The quality figure's third panel is |A − B| × gain per channel, by hand: pixels
    /// (1, 2, 3) and (0.5, 0.5, 0.5) against (2, 2, 1) and (0.25, 0.75, 0.5) at gain 4 give
    /// (4, 0, 8) and (1, 1, 0), all exact in binary. A signed difference gave −4 and −1
    /// where B is the brighter, which the PNG clips to black: half the differences unseen.
    #[test]
    fn the_difference_is_absolute_and_scaled() {
        let mut a = RgbImage::new(2, 1);
        a.pixels = vec![[1.0, 2.0, 3.0], [0.5, 0.5, 0.5]];
        let mut b = RgbImage::new(2, 1);
        b.pixels = vec![[2.0, 2.0, 1.0], [0.25, 0.75, 0.5]];
        let d = difference(&a, &b, 4.0);
        assert_eq!((d.width, d.height), (2, 1));
        assert_eq!(d.pixels, vec![[4.0, 0.0, 8.0], [1.0, 1.0, 0.0]]);
    }
}
