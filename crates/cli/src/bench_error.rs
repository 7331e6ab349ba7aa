//! `stcvae bench error`: any renderer's images (stcvae's, Mitsuba's, pbrt's, Cycles') against
//! a reference, so that renderers can be compared at equal error rather than at equal
//! samples. The reference is the mean of independent renders, and its own noise, estimated
//! from their spread, is subtracted from every image's MSE: with a reference of a few
//! thousand spp that noise is of the order of the error being measured.

use std::path::{Path, PathBuf};

use anyhow::{Result, anyhow, bail};
use render_gpu::image_io::{RenderTag, RgbImage, read_exr};

use crate::plots::{Series, line_plot};

#[derive(clap::Args)]
#[command(
    after_help = "Example (docs/compare/README.md: stcvae against Mitsuba 3):\n  \
    stcvae bench error --reference ref_1.exr,ref_2.exr,ref_3.exr,ref_4.exr \\\n    \
    pt_256.exr:27.1 stcvae_256.exr:5.5 mitsuba_r.exr,mitsuba_g.exr,mitsuba_b.exr:88.1\n\n\
    The same with lines drawn (RMSE against seconds; one line per label):\n  \
    stcvae bench error --reference ref_1.exr,ref_2.exr,ref_3.exr,ref_4.exr --plot error.png \\\n    \
    ST-CVAE=st_64.exr:1.4 ST-CVAE=st_256.exr:5.5 PT=pt_256.exr:27.1\n\n\
    RMSE is noise-corrected: sqrt(mean((image − reference)²) − mean(Var(reference mean))), \
    Var(reference mean) being the renders' sample variance over their count; 0 where the \
    difference is below the reference's own noise. The images must be independent of the \
    references (other seeds); a file given twice is refused, and so is an stcvae render of \
    another scene than the references' (their tags record what the image shows, whichever \
    integrator drew it; other renderers' images are not checked). MSE·s is the MSE times the \
    render's seconds; `vs first` divides it by the first timed image's: how much longer that \
    renderer takes to reach the same error, as long as its MSE falls as 1/time (a biased \
    renderer's does not at errors near its bias, so compare at the errors measured).\n\n\
    A name that is an existing file is taken whole, even with '=', ',' or ':' in it."
)]
pub struct Args {
    /// Independent renders of the scene (different seeds), EXR: their mean is the reference,
    /// and their spread its noise (give two or more, comma-separated or the option
    /// repeated; with one, no correction is made).
    #[arg(long, required = true)]
    reference: Vec<String>,
    /// Images to measure: FILE.exr, or R.exr,G.exr,B.exr (a renderer run once per colour
    /// channel: channel c is taken from the c-th file), each optionally followed by
    /// :SECONDS, its render time, for the MSE·s and equal-error columns, and optionally
    /// preceded by LABEL=, the line it belongs to in --plot.
    #[arg(required = true)]
    images: Vec<String>,
    /// Pixels whose reference R + G + B exceeds this are the object's: the image's mean
    /// over them, over the reference's, is printed per channel (a brightness offset shows
    /// there first).
    #[arg(long, default_value_t = 0.2)]
    object_threshold: f64,
    /// Also draw RMSE against seconds (log-log) into this PNG, one line per label: give the
    /// images as LABEL=FILE:SECONDS (e.g. `Cycles=c_64.exr:2.7 Cycles=c_256.exr:10.6`); an
    /// unlabelled image is a line of its own. An unbiased renderer's line falls with slope
    /// −1/2; a biased one levels off at its bias.
    #[arg(long, value_name = "FILE.png")]
    plot: Option<PathBuf>,
}

/// The mean of the reference renders, the mean variance of that mean (its noise), and which
/// pixels are the object's.
pub struct Reference {
    pub width: usize,
    pub height: usize,
    pub mean: Vec<[f64; 3]>,
    /// The mean over pixels and channels of Var(`mean`) (the renders' sample variance over
    /// their count; 0 for one render): what the reference's noise adds to every image's
    /// mean squared difference from it.
    pub noise_mse: f64,
    /// Pixels whose mean R + G + B exceeds the object threshold.
    pub object: Vec<bool>,
}

impl Reference {
    /// `images` must share one size and hold finite pixels (checked by [`load`]).
    pub fn new(images: &[RgbImage], object_threshold: f64) -> Self {
        let n = images.len() as f64;
        let (width, height) = (images[0].width, images[0].height);
        let pixels = width * height;
        let mut var_sum = 0.0;
        let mean: Vec<[f64; 3]> = (0..pixels)
            .map(|i| {
                std::array::from_fn(|c| {
                    let v = || images.iter().map(|im| im.pixels[i][c] as f64);
                    let m = v().sum::<f64>() / n;
                    if images.len() > 1 {
                        var_sum += v().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0) / n;
                    }
                    m
                })
            })
            .collect();
        let noise_mse = var_sum / (3 * pixels) as f64;
        let object = mean
            .iter()
            .map(|m| m.iter().sum::<f64>() > object_threshold)
            .collect();
        Self {
            width,
            height,
            mean,
            noise_mse,
            object,
        }
    }
}

/// One image against the reference.
#[derive(Debug)]
pub struct Measure {
    /// mean((image − reference)²) − mean(Var(reference mean)): an unbiased estimate of the
    /// image's own MSE (noise + bias²) when the two are independent; may come out < 0.
    pub mse: f64,
    /// The image's mean over the object's pixels over the reference's, per channel.
    pub object_ratio: [f64; 3],
}

pub fn measure(r: &Reference, image: &RgbImage) -> Measure {
    let mut sum = 0.0;
    let mut obj = [[0.0f64; 2]; 3];
    for ((p, m), &is_object) in image.pixels.iter().zip(&r.mean).zip(&r.object) {
        for c in 0..3 {
            sum += (p[c] as f64 - m[c]).powi(2);
            if is_object {
                obj[c][0] += p[c] as f64;
                obj[c][1] += m[c];
            }
        }
    }
    Measure {
        mse: sum / (3 * image.pixels.len()) as f64 - r.noise_mse,
        object_ratio: obj.map(|[a, b]| if b > 0.0 { a / b } else { f64::NAN }),
    }
}

/// Reads an EXR and refuses non-finite pixels (an image with a NaN would make every figure
/// NaN without saying where it came from).
/// What the inputs record about their renders, for [`check_shared_seeds`].
#[derive(Default)]
struct Seen {
    /// stcvae's render tags (scene hash, seeds).
    tags: Vec<(PathBuf, RenderTag)>,
    /// Every input's pixel digest (None for a constant image), tagged or not.
    digests: Vec<(PathBuf, Option<u64>)>,
}

fn load(path: &Path, seen: &mut Seen) -> Result<RgbImage> {
    let (img, tag) = read_exr(path)?;
    // Other renderers' images are untagged too, but `render --variance`'s are named so:
    // one given as a reference or an image was measured as a render without a word.
    if tag.is_none() && path.to_string_lossy().ends_with(".var.exr") {
        bail!(
            "{}: a variance image of `render --variance` (untagged, named *.var.exr), not a \
             render: leave it out",
            path.display()
        );
    }
    if let Some(t) = tag {
        // An stcvae render's pixels are ≥ 0 (`merge` refuses others too). Other
        // renderers' may not be: a spectral-to-RGB conversion leaves small negatives.
        if let Some((x, y, v)) = img.first_value(|v| v < 0.0) {
            bail!(
                "{}: pixel ({x}, {y}) is {v}: an stcvae render's pixels are ≥ 0 (a damaged \
                 file?)",
                path.display()
            );
        }
        seen.tags.push((path.to_path_buf(), t));
    }
    seen.digests.push((path.to_path_buf(), img.pixel_digest()));
    if let Some((x, y)) = img.first_non_finite() {
        bail!(
            "{}: pixel ({x}, {y}) is not finite: {:?}",
            path.display(),
            img.pixels[y * img.width + x]
        );
    }
    Ok(img)
}

fn same_size(path: &str, img: &RgbImage, w: usize, h: usize) -> Result<()> {
    if (img.width, img.height) != (w, h) {
        bail!(
            "{path}: {}x{} pixels, the reference has {w}x{h}",
            img.width,
            img.height
        );
    }
    Ok(())
}

/// The files a comma-separated list names: the whole text where it is an existing file
/// (a name with a comma in it), else its parts, none of them empty.
fn file_list(what: &str, text: &str) -> Result<Vec<String>> {
    if Path::new(text).is_file() {
        return Ok(vec![text.to_string()]);
    }
    let parts: Vec<String> = text.split(',').map(str::to_string).collect();
    if parts.iter().any(|p| p.is_empty()) {
        bail!("{what} `{text}`: empty file name");
    }
    Ok(parts)
}

/// An image argument: its plot label, its files (one, or one per channel) and its seconds.
/// An existing file's whole name is the image, whatever it holds. Otherwise the text after
/// the last ':' is the seconds where it is a number (a ':' in a name, a Windows drive,
/// stays), and the text before the first '=' is the label, unless what remains names
/// existing files without it (`out/k=8/st.exr:1.5` has no label).
fn parse_spec(arg: &str) -> Result<Spec> {
    if Path::new(arg).is_file() {
        return Ok(Spec {
            label: None,
            files: vec![arg.to_string()],
            seconds: None,
        });
    }
    let (body, seconds) = match arg.rsplit_once(':') {
        Some((f, s)) => match s.parse::<f64>() {
            // A microsecond to 30 years: 1e-300 and 1e300 printed `inf` ratios and a plot
            // axis 600 decades long.
            Ok(t) if (1e-6..=1e9).contains(&t) => (f, Some(t)),
            Ok(_) => bail!("image `{arg}`: the seconds must be in [1e-6, 1e9], got {s}"),
            Err(_) if s.is_empty() => bail!("image `{arg}`: no seconds after the ':'"),
            // `img.exr:abc` read as a file name said "No such file": the file is there.
            Err(_)
                if Path::new(f).is_file()
                    || f.rsplit(['=', ','])
                        .next()
                        .is_some_and(|n| Path::new(n).is_file()) =>
            {
                bail!("image `{arg}`: `{s}` after the ':' is not a number of seconds")
            }
            Err(_) => (arg, None),
        },
        None => (arg, None),
    };
    let names_files = |text: &str| {
        file_list("image", text).is_ok_and(|f| f.iter().all(|p| Path::new(p).is_file()))
    };
    let (label, text) = match body.split_once('=') {
        Some((l, rest)) if !names_files(body) => {
            if l.is_empty() || rest.is_empty() {
                bail!("image `{arg}`: give LABEL=FILE, neither of them empty");
            }
            (Some(l.to_string()), rest)
        }
        _ => (None, body),
    };
    let files = file_list("image", text).map_err(|_| anyhow!("image `{arg}`: empty file name"))?;
    if files.len() != 1 && files.len() != 3 {
        bail!(
            "image `{arg}`: give one EXR or three (R,G,B: one render per channel), not {}",
            files.len()
        );
    }
    Ok(Spec {
        label,
        files,
        seconds,
    })
}

/// One image argument, parsed.
#[derive(Debug, PartialEq)]
struct Spec {
    label: Option<String>,
    files: Vec<String>,
    seconds: Option<f64>,
}

/// Refuses a file named twice among the references and images: a repeated reference would
/// hide its noise, and an image that is also a reference is not independent of it.
fn check_distinct(names: &[&str]) -> Result<()> {
    let ids: Vec<PathBuf> = names
        .iter()
        .map(|n| crate::paths::identity(Path::new(n)))
        .collect();
    for (i, id) in ids.iter().enumerate() {
        if let Some(j) = ids[..i].iter().position(|x| x == id) {
            bail!(
                "{} and {} are the same file: the references and images must be independent \
                 renders (other seeds)",
                names[j],
                names[i]
            );
        }
    }
    Ok(())
}

/// Refuses two stcvae renders that share a seed: on one device they share random numbers
/// (the CPU and the GPU draw different streams from a seed, but the tag does not record
/// the device, so a pair from different devices is refused too), so an image
/// would match a reference by more than the image's accuracy (an image rendered with a
/// reference's seed read RMSE 0). Whatever their scene hashes: an ST-CVAE image and a PT
/// reference of one scene differ in hash (the integrator is in it), yet with one seed they
/// draw the same camera rays and first numbers and correlate (experiment::measure gives
/// the two integrators different seeds for that reason). Files without stcvae's tag
/// (other renderers' EXRs) are compared by their pixels, as `merge` compares seedless
/// files: a copy of a reference reads RMSE 0 too.
/// Images may share seeds with each other: each is measured against the references only.
fn check_shared_seeds(references: &Seen, images: &Seen) -> Result<()> {
    let tags = &references.tags;
    for (i, (pa, a)) in tags.iter().chain(&images.tags).enumerate() {
        for (pb, b) in &tags[..i.min(tags.len())] {
            if let Some(seed) = a.seeds.iter().find(|s| b.seeds.contains(s)) {
                bail!(
                    "{} and {} are renders with seed {seed} in common: on one device they \
                     share random numbers (whichever integrator drew them), and their tags do \
                     not record the device, so the error could read low; render them with \
                     other seeds",
                    pb.display(),
                    pa.display()
                );
            }
        }
    }
    let all = references.digests.iter().chain(&images.digests);
    for (i, (pa, a)) in all.enumerate() {
        let earlier = &references.digests[..i.min(references.digests.len())];
        if let Some((pb, _)) = earlier.iter().find(|(_, b)| a.is_some() && a == b) {
            bail!(
                "{} and {} hold the same pixels: the same render (a copy, or the same seed), \
                 so the error would read low; compare independent renders",
                pb.display(),
                pa.display()
            );
        }
    }
    Ok(())
}

/// Refuses stcvae renders of different views: an image of another scene (another camera,
/// mesh, medium or light) than the reference's, of the same size, would be measured
/// against it and read as a large error without a word. The scene hash cannot tell (it
/// holds the integrator and its settings, so an ST-CVAE image and its PT reference always
/// differ there); the view hash leaves those out. Files without one (other renderers',
/// older renders) are not checked.
fn check_views(references: &Seen, images: &Seen) -> Result<()> {
    let mut views = references
        .tags
        .iter()
        .chain(&images.tags)
        .filter_map(|(p, t)| Some((p, t.view_hash?)));
    if let Some((p0, v0)) = views.next()
        && let Some((p, v)) = views.find(|&(_, v)| v != v0)
    {
        bail!(
            "{} and {} show different scenes (view hashes {v0:016x} and {v:016x}: their \
             camera, object, medium, boundary, lights or environment differ): every image \
             must be a render of the references' scene",
            p0.display(),
            p.display()
        );
    }
    Ok(())
}

/// The image an argument names, checked against the reference's size.
fn load_spec(files: &[String], w: usize, h: usize, seen: &mut Seen) -> Result<RgbImage> {
    let mut images = Vec::with_capacity(files.len());
    for f in files {
        let img = load(Path::new(f), seen)?;
        same_size(f, &img, w, h)?;
        images.push(img);
    }
    if images.len() == 1 {
        return Ok(images.pop().expect("one image"));
    }
    let mut out = RgbImage::new(w, h);
    for (i, p) in out.pixels.iter_mut().enumerate() {
        for (c, v) in p.iter_mut().enumerate() {
            *v = images[c].pixels[i][c];
        }
    }
    Ok(out)
}

pub fn run(a: Args) -> Result<()> {
    let (specs, references) = read_args(&a)?;
    let (refs, ref_seen) = read_references(&references)?;
    let r = Reference::new(&refs, a.object_threshold);
    // Every image is read before anything is printed, so a bad one leaves no half table.
    let mut image_seen = Seen::default();
    let images: Vec<RgbImage> = specs
        .iter()
        .map(|s| load_spec(&s.files, r.width, r.height, &mut image_seen))
        .collect::<Result<_>>()?;
    check_shared_seeds(&ref_seen, &image_seen)?;
    check_views(&ref_seen, &image_seen)?;
    let ref_noise = r.noise_mse.sqrt();
    let objects = r.object.iter().filter(|&&o| o).count();
    note_object_pixels(&r, objects, a.object_threshold);
    println!(
        "stcvae bench error: reference = mean of {} render(s), {}x{}, {}; {objects} object pixels (R+G+B > {})",
        refs.len(),
        r.width,
        r.height,
        if refs.len() > 1 {
            format!("its own noise RMSE {ref_noise:.4} (subtracted)")
        } else {
            "no noise estimate with one render (nothing subtracted)".into()
        },
        scatter_sim::ranges::num(a.object_threshold)
    );
    println!(
        "{:<40} {:>9} {:>9} {:>10} {:>9}  object mean / reference (R, G, B)",
        "image", "seconds", "RMSE", "MSE·s", "vs first"
    );
    // The first timed image's MSE·s; equal-error ratios need it > 0.
    let mut first: Option<f64> = None;
    let mut lines: Vec<Series> = Vec::new();
    for (spec, img) in specs.iter().zip(&images) {
        let (files, seconds) = (&spec.files, spec.seconds);
        let m = measure(&r, img);
        // Below the reference's noise the MSE estimate may be ≤ 0: shown as 0, and no
        // ratio is formed with it.
        let mse = m.mse.max(0.0);
        let cost = seconds.map(|s| mse * s);
        let vs = match (cost, first) {
            (Some(c), Some(f)) if f > 0.0 => format!("{:.2}", c / f),
            (Some(_), None) if mse > 0.0 => "1".into(),
            (Some(_), _) => "n/a".into(),
            (None, _) => String::new(),
        };
        if first.is_none() {
            first = cost;
        }
        // A per-channel triple is named by its first file (the others differ by channel).
        let name = match files.as_slice() {
            [one] => one.clone(),
            [r, ..] => format!("{r} (+G, B)"),
            [] => unreachable!("parse_spec gives one or three files"),
        };
        let ratios = if objects == 0 {
            "(no object pixels)".to_string()
        } else {
            // A channel the reference leaves black on the object has no ratio.
            let [or, og, ob] = m.object_ratio.map(|v| {
                if v.is_finite() {
                    format!("{v:.3}")
                } else {
                    "n/a".to_owned()
                }
            });
            format!("{or}, {og}, {ob}")
        };
        println!(
            "{name:<40} {:>9} {:>9.4} {:>10} {:>9}  {ratios}",
            seconds.map_or(String::new(), crate::progress::significant4),
            mse.sqrt(),
            cost.map_or(String::new(), crate::progress::significant4),
            vs,
        );
        if let Some(t) = seconds {
            let line = spec.label.clone().unwrap_or(name);
            match lines.iter_mut().find(|s| s.name == line) {
                Some(s) => s.points.push((t, mse.sqrt())),
                None => lines.push(Series::new(line, vec![(t, mse.sqrt())])),
            }
        }
    }
    if let Some(path) = &a.plot {
        draw_plot(path, &mut lines)?;
    }
    Ok(())
}

/// The image specifications and the reference files, with the options checked before any
/// image is read.
fn read_args(a: &Args) -> Result<(Vec<Spec>, Vec<String>)> {
    if !(a.object_threshold.is_finite() && a.object_threshold >= 0.0) {
        bail!(
            "--object-threshold {}: must be a finite number ≥ 0",
            a.object_threshold
        );
    }
    let specs: Vec<Spec> = a
        .images
        .iter()
        .map(|s| parse_spec(s))
        .collect::<Result<_>>()?;
    if a.plot.is_some() && specs.iter().all(|s| s.seconds.is_none()) {
        bail!("--plot: no image has :SECONDS, its render time (the plot's x axis)");
    }
    // A folder, a file in the way or an unwritable place fails now, not after the table.
    if let Some(path) = &a.plot {
        crate::check_out("--plot", path)?;
    }
    let mut references = Vec::new();
    for r in &a.reference {
        references.extend(file_list("--reference", r)?);
    }
    let names: Vec<&str> = references
        .iter()
        .chain(specs.iter().flat_map(|s| s.files.iter()))
        .map(String::as_str)
        .collect();
    check_distinct(&names)?;
    if let Some(path) = &a.plot {
        if !path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("png"))
        {
            bail!(
                "--plot {}: the plot is a PNG; name the file *.png",
                path.display()
            );
        }
        let inputs: Vec<(String, PathBuf)> = names
            .iter()
            .map(|n| (format!("an input image ({n})"), PathBuf::from(n)))
            .collect();
        crate::paths::check_not_input("--plot", path, &inputs)?;
    }
    Ok((specs, references))
}

/// The reference renders, of one size and one scene.
fn read_references(references: &[String]) -> Result<(Vec<RgbImage>, Seen)> {
    let mut ref_seen = Seen::default();
    let mut refs: Vec<RgbImage> = Vec::with_capacity(references.len());
    for p in references {
        let img = load(Path::new(p), &mut ref_seen)?;
        if let Some(first) = refs.first() {
            same_size(p, &img, first.width, first.height)?;
        }
        refs.push(img);
    }
    // Renders of different scenes (another density, light or estimator) would be averaged
    // as one reference, their difference counted as its noise and subtracted from every
    // image's error.
    if let Some(((pa, ta), (pb, tb))) = ref_seen
        .tags
        .iter()
        .zip(ref_seen.tags.iter().skip(1))
        .find(|((_, a), (_, b))| a.scene_hash != b.scene_hash)
    {
        bail!(
            "{} and {} are renders of different scenes or render settings (scene hashes \
             {:016x} and {:016x}): the references must be renders of one scene",
            pa.display(),
            pb.display(),
            ta.scene_hash,
            tb.scene_hash
        );
    }
    Ok((refs, ref_seen))
}

/// Says when the object column covers the whole image, or none of it.
fn note_object_pixels(r: &Reference, objects: usize, threshold: f64) {
    // A sky brighter than the threshold makes every pixel the object's (sphere.toml's 0.1
    // per channel), and the object column then measures the whole frame.
    let sums = || r.mean.iter().map(|m| m.iter().sum::<f64>());
    if objects == r.object.len() {
        eprintln!(
            "note: every pixel's R + G + B exceeds --object-threshold {}, the background's \
             too: the object column covers the whole image; give a threshold above the \
             background's (the image's least is {:.4})",
            scatter_sim::ranges::num(threshold),
            sums().fold(f64::INFINITY, f64::min)
        );
    } else if objects == 0 {
        eprintln!(
            "note: no pixel's R + G + B exceeds --object-threshold {}: the object column is \
             empty; give a threshold below the object's (the image's greatest is {:.4})",
            scatter_sim::ranges::num(threshold),
            sums().fold(f64::NEG_INFINITY, f64::max)
        );
    }
}

/// The RMSE-against-time plot of the timed images, one line a label.
fn draw_plot(path: &Path, lines: &mut [Series]) -> Result<()> {
    if lines.iter().flat_map(|s| &s.points).all(|p| p.1 <= 0.0) {
        bail!(
            "--plot: every timed image's RMSE is 0 (below the reference's own noise): \
             nothing to draw on a log axis"
        );
    }
    for s in lines.iter_mut() {
        s.points.sort_by(|p, q| p.0.total_cmp(&q.0));
    }
    // An RMSE of 0 (below the reference's noise) has no place on a log axis: the plot
    // leaves it out, and the table above shows it.
    line_plot(
        path,
        "RMSE against render time (noise-corrected)",
        "seconds",
        "RMSE",
        (true, true),
        lines,
    )?;
    println!("plot: {}", path.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use scatter_sim::rng::WalkRng;

    /// With one reference render there is no spread to estimate its noise from: nothing
    /// is subtracted (0/0 made the noise, and every figure, NaN).
    #[test]
    fn one_reference_render_has_no_noise_to_subtract() {
        let r = Reference::new(&[image(2, 2, |i, c| (i + c) as f32)], 0.0);
        assert_eq!(r.noise_mse, 0.0);
        // 0.5 above the reference in every channel of every pixel: an MSE of 0.25 exactly.
        let m = measure(&r, &image(2, 2, |i, c| (i + c) as f32 + 0.5));
        assert_eq!(m.mse, 0.25);
    }

    /// Constant images (the object out of view or unlit: every seed gives them) have no
    /// digest and are never taken for copies; varied ones still are.
    #[test]
    fn constant_images_are_not_taken_for_copies() {
        fn seen(d: &[(&str, Option<u64>)]) -> Seen {
            Seen {
                tags: Vec::new(),
                digests: d.iter().map(|&(p, h)| (PathBuf::from(p), h)).collect(),
            }
        }
        let flat = image(2, 2, |_, _| 0.1).pixel_digest();
        let varied = image(2, 2, |i, c| (3 * i + c) as f32).pixel_digest();
        assert!(flat.is_none() && varied.is_some());
        check_shared_seeds(
            &seen(&[("r1.exr", flat), ("r2.exr", flat)]),
            &seen(&[("a.exr", flat), ("b.exr", varied)]),
        )
        .unwrap();
        let e = check_shared_seeds(
            &seen(&[("r1.exr", varied), ("r2.exr", flat)]),
            &seen(&[("a.exr", varied)]),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("r1.exr and a.exr hold the same pixels"), "{e}");
    }

    fn image(w: usize, h: usize, mut f: impl FnMut(usize, usize) -> f32) -> RgbImage {
        let mut img = RgbImage::new(w, h);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            for (c, v) in p.iter_mut().enumerate() {
                *v = f(i, c);
            }
        }
        img
    }

    /// The noise-corrected MSE of a test image with known bias b and noise σ_t against a
    /// reference of four renders with noise σ_r = 2σ_t (more noise in the reference than
    /// in the image, as with a short reference) estimates b² + σ_t², not b² + σ_t² + σ_r²/4.
    /// Threshold: the estimate is a mean over 3·96² terms, whose standard error is computed
    /// from the same terms; 4 standard errors leave a 6e-5 false-failure chance, and the
    /// uncorrected MSE lies ~50 standard errors away, so the test can fail.
    #[test]
    fn the_reference_noise_is_subtracted() {
        let (w, h) = (96, 96);
        // Channels of different brightness (1 : 1.5 : 2), so that a channel's ratio taken
        // against another channel's reference shows.
        let truth = |i: usize, c: usize| {
            (0.2 + 0.5 * ((i * 7 + c * 13) % 29) as f32 / 29.0) * [1.0, 1.5, 2.0][c]
        };
        let mut rng = WalkRng::from_seed(5);
        let (sr, st, b) = (0.2f32, 0.1f32, 0.05f32);
        let refs: Vec<RgbImage> = (0..4)
            .map(|_| image(w, h, |i, c| truth(i, c) + sr * rng.standard_normal()))
            .collect();
        let test = image(w, h, |i, c| truth(i, c) + b + st * rng.standard_normal());
        let r = Reference::new(&refs, 0.0);
        let m = measure(&r, &test);
        // Per-term values of the estimator, for its standard error: each squared difference
        // less the variance of the reference's mean, computed here from the renders.
        let var_of_mean = |i: usize, c: usize| {
            let v: Vec<f64> = refs.iter().map(|im| im.pixels[i][c] as f64).collect();
            let m = v.iter().sum::<f64>() / 4.0;
            v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / 3.0 / 4.0
        };
        let terms: Vec<f64> = test
            .pixels
            .iter()
            .enumerate()
            .flat_map(|(i, p)| {
                let r = &r;
                (0..3).map(move |c| (p[c] as f64 - r.mean[i][c]).powi(2) - var_of_mean(i, c))
            })
            .collect();
        let n = terms.len() as f64;
        let mean = terms.iter().sum::<f64>() / n;
        let se = (terms.iter().map(|t| (t - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
        assert!((mean - m.mse).abs() < 1e-12, "{mean} against {}", m.mse);
        let expected = (b * b + st * st) as f64;
        let uncorrected = expected + (sr * sr) as f64 / 4.0;
        assert!(
            (m.mse - expected).abs() < 4.0 * se,
            "MSE {} against {expected} (SE {se})",
            m.mse
        );
        assert!(
            (uncorrected - expected) > 10.0 * se,
            "the test must tell the corrected MSE from the uncorrected one (SE {se})"
        );
        // Each channel's brightness ratio sees the bias: (mean truth + b) / mean truth.
        // The ratio's noise: the image's mean has σ_t/96 = 0.0010 and the reference's
        // (σ_r/2)/96 = 0.0010, over a mean of 0.44 (channel 0; 0.66 and 0.88 the others):
        // a standard error of at most ~0.0035, so 0.015 is ≥ 4.25 of them, and the bias
        // moves the ratios by 0.113, 0.076 and 0.057 (a channel divided by channel 0's
        // reference would be off by 0.5 and 1).
        for c in 0..3 {
            let truth_mean = (0..w * h).map(|i| truth(i, c) as f64).sum::<f64>() / (w * h) as f64;
            let want = (truth_mean + b as f64) / truth_mean;
            assert!(
                (m.object_ratio[c] - want).abs() < 0.015,
                "channel {c}: {:?} against {want}",
                m.object_ratio
            );
        }
    }

    /// An image given as R.exr,G.exr,B.exr (a renderer run once per colour channel) takes
    /// channel c from the c-th file. Worked case: file k holds 10k + c + 1 in channel c of
    /// every pixel, a value of its own per (file, channel), so the image is (1, 12, 23);
    /// every channel from the first file would read (1, 2, 3), each file's red (1, 11, 21).
    #[test]
    fn a_per_channel_triple_takes_each_channel_from_its_own_file() {
        let d = tempfile::tempdir().unwrap();
        let files: Vec<String> = (0..3)
            .map(|k: usize| {
                let img = image(2, 2, |_, c| (10 * k + c + 1) as f32);
                let path = d.path().join(format!("c{k}.exr"));
                let bytes = render_gpu::image_io::encode_untagged_exr(&img).unwrap();
                std::fs::write(&path, bytes).unwrap();
                path.to_str().unwrap().to_string()
            })
            .collect();
        let img = load_spec(&files, 2, 2, &mut Seen::default()).unwrap();
        assert_eq!((img.width, img.height), (2, 2));
        for p in &img.pixels {
            assert_eq!(*p, [1.0, 12.0, 23.0]);
        }
    }

    #[test]
    fn image_arguments_parse_or_say_why_not() {
        let v = |label: Option<&str>, names: &[&str], seconds| Spec {
            label: label.map(str::to_string),
            files: names.iter().map(|n| n.to_string()).collect(),
            seconds,
        };
        assert_eq!(parse_spec("a.exr").unwrap(), v(None, &["a.exr"], None));
        assert_eq!(
            parse_spec("r.exr,g.exr,b.exr:12.5").unwrap(),
            v(None, &["r.exr", "g.exr", "b.exr"], Some(12.5))
        );
        assert_eq!(
            parse_spec("Mitsuba grey=r.exr,g.exr,b.exr:12.5").unwrap(),
            v(
                Some("Mitsuba grey"),
                &["r.exr", "g.exr", "b.exr"],
                Some(12.5)
            )
        );
        // A ':' not followed by a number belongs to the name (C:\x.exr).
        assert_eq!(
            parse_spec("C:\\x.exr").unwrap(),
            v(None, &["C:\\x.exr"], None)
        );
        assert_eq!(
            parse_spec("PT=C:\\x.exr:3").unwrap(),
            v(Some("PT"), &["C:\\x.exr"], Some(3.0))
        );
        // Each refusal, and what its one-line error must say.
        for (bad, says) in [
            ("=a.exr", "`=a.exr`: give LABEL=FILE"),
            ("PT=", "`PT=`: give LABEL=FILE"),
            ("PT=:3", "`PT=:3`: give LABEL=FILE"),
            ("PT=a.exr,,b.exr:3", "`PT=a.exr,,b.exr:3`: empty file name"),
            ("ST=a.exr:", "`ST=a.exr:`"),
            ("a.exr,b.exr", "three (R,G,B"),
            ("a.exr:", "no seconds"),
            ("a.exr:0", "must be in [1e-6, 1e9], got 0"),
            ("a.exr:1e300", "must be in [1e-6, 1e9], got 1e300"),
            ("a.exr,,b.exr", "empty file name"),
        ] {
            let e = parse_spec(bad).unwrap_err().to_string();
            assert!(e.contains(says), "{bad}: {e}");
        }
        // An existing file's name is taken whole, commas and all.
        let d = tempfile::tempdir().unwrap();
        let odd = d.path().join("a=b,c:3");
        std::fs::write(&odd, b"").unwrap();
        let odd = odd.to_str().unwrap();
        assert_eq!(parse_spec(odd).unwrap(), v(None, &[odd], None));
        // ... and so is one with '=' in it before the seconds, or in a folder's name.
        let eq = d.path().join("a=b.exr");
        std::fs::write(&eq, b"").unwrap();
        let eq = eq.to_str().unwrap();
        assert_eq!(
            parse_spec(&format!("{eq}:6.5")).unwrap(),
            v(None, &[eq], Some(6.5))
        );
        std::fs::create_dir(d.path().join("k=8")).unwrap();
        let deep = d.path().join("k=8").join("st.exr");
        std::fs::write(&deep, b"").unwrap();
        let deep = deep.to_str().unwrap();
        assert_eq!(
            parse_spec(&format!("{deep}:1.5")).unwrap(),
            v(None, &[deep], Some(1.5))
        );
        assert_eq!(
            parse_spec(&format!("ST={deep}:1.5")).unwrap(),
            v(Some("ST"), &[deep], Some(1.5))
        );
        let x = d.path().join("x.exr");
        std::fs::write(&x, b"").unwrap();
        let again = d.path().join(".").join("x.exr");
        let (x, again) = (x.to_str().unwrap(), again.to_str().unwrap());
        let e = check_distinct(&[x, "y.exr", again])
            .unwrap_err()
            .to_string();
        assert!(e.contains("same file"), "{e}");
        check_distinct(&[x, "y.exr"]).unwrap();
    }
}
