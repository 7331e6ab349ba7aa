//! Render outputs: linear float EXR with the render's identity in its header, a
//! tone-mapped PNG preview, and averaging of EXRs of the same scene (`stcvae merge`).
//!
//! Every file is written to a temporary name and renamed, so an interrupted run never
//! leaves a half-written image under the output name.

use std::collections::HashMap;
use std::io::Cursor;
use std::path::Path;

use exr::prelude::*;
use scatter_sim::output::write_atomic;

use crate::error::RenderError;

/// The render tag as one text attribute, `spp=N scene=HEX [view=HEX] [seed=S |
/// seeds=S,S,…]`, where a `?` in the list stands for inputs of unknown seed, `?HEX` for
/// one whose pixel digest is HEX (see [`RenderTag::partial`] and
/// [`RenderTag::unknown_digests`]). One attribute, not three: the exr crate keeps custom
/// attributes in a HashMap, whose order (and so the file's bytes) changed from run to run
/// with three.
const ATTR_TAG: &str = "stcvaeTag";
/// The three attributes that files written before `ATTR_TAG` carry (still read).
const ATTR_SPP: &str = "stcvaeSpp";
const ATTR_SCENE: &str = "stcvaeSceneHash";
const ATTR_SEED: &str = "stcvaeSeed";

/// A linear RGB image, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<[f32; 3]>,
}

impl RgbImage {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            pixels: vec![[0.0; 3]; width * height],
        }
    }

    /// The first pixel (x, y) with a NaN or infinite channel: a reader that averages or
    /// compares images refuses it by name rather than spread it through every figure.
    pub fn first_non_finite(&self) -> Option<(usize, usize)> {
        self.first_value(|v| !v.is_finite()).map(|(x, y, _)| (x, y))
    }

    /// A hash of the pixels' bits, or None for a constant image. Two renders whose pixels
    /// are the same share their samples (a copy, or the same seed); a constant image (an
    /// object out of view or unlit) is what every seed gives, so it proves nothing.
    pub fn pixel_digest(&self) -> Option<u64> {
        let first = self.pixels.first()?;
        self.pixels.iter().any(|px| px != first).then(|| {
            let mut h = crate::hash::Fnv64::new();
            for px in &self.pixels {
                for v in px {
                    h.write(&v.to_bits().to_le_bytes());
                }
            }
            h.finish()
        })
    }

    /// The first pixel (x, y) with a channel value v for which `bad(v)`, and that value:
    /// the readers' checks of what an image may hold name the pixel they refuse.
    pub fn first_value(&self, bad: impl Fn(f32) -> bool) -> Option<(usize, usize, f32)> {
        self.pixels.iter().enumerate().find_map(|(i, p)| {
            let v = p.iter().copied().find(|v| bad(*v))?;
            Some((i % self.width, i / self.width, v))
        })
    }
}

/// What an EXR header records about the render it holds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RenderTag {
    pub spp: u64,
    /// Hash of everything that defines the image except spp and seed.
    pub scene_hash: u64,
    /// The seeds of the renders the image holds: one for a render, each input's for a
    /// merge (empty where unknown: files written before seeds were recorded, averages of
    /// paired renders). Renders with a seed in common share its samples, so `merge`
    /// refuses two such images, a merge and one of its own inputs included.
    pub seeds: Vec<u64>,
    /// Whether the image also holds renders of unknown seed besides `seeds` (a merge with
    /// such an input). The known seeds are kept all the same: dropping them (as merges
    /// once did) let the merge take one of its own inputs again, counting its samples
    /// twice. An empty `seeds` is unknown whatever this says.
    pub partial: bool,
    /// The pixel digests ([`RgbImage::pixel_digest`]) of the renders of unknown seed in a
    /// merge, where their pixels vary: the only way to know one of them again (without
    /// them a merge M of a and u accepted u once more, and again).
    pub unknown_digests: Vec<u64>,
    /// What the image shows whichever integrator rendered it
    /// ([`crate::setup::SceneData::view_hash`]); None in files written before it was
    /// recorded, and in a merge of such a file.
    pub view_hash: Option<u64>,
}

impl RenderTag {
    /// Whether some of the image's renders have no known seed.
    pub fn some_unknown(&self) -> bool {
        self.partial || self.seeds.is_empty()
    }
}

/// The fields of a tag text, each once: `spp`, `scene`, `view` and one of `seed` /
/// `seeds`. Anything else (an unknown or repeated key, both seed forms, a repeated seed)
/// means a damaged or hand-edited file, which `merge` must not trust with its seed
/// bookkeeping.
fn parse_tag_text(t: &str) -> Option<[Option<String>; 4]> {
    let mut fields: [Option<String>; 5] = Default::default();
    for kv in t.split(' ').filter(|kv| !kv.is_empty()) {
        let (k, v) = kv.split_once('=')?;
        let i = ["spp", "scene", "seed", "seeds", "view"]
            .iter()
            .position(|&n| n == k)?;
        if fields[i].replace(v.to_string()).is_some() {
            return None;
        }
    }
    let [spp, scene, seed, seeds, view] = fields;
    if seed.is_some() && seeds.is_some() {
        return None;
    }
    Some([spp, scene, seed.or(seeds), view])
}

pub fn write_exr(
    path: &Path,
    img: &RgbImage,
    tag: &RenderTag,
) -> std::result::Result<(), RenderError> {
    let bytes = encode_exr(img, tag).map_err(|e| RenderError::io(path, e))?;
    write_atomic(path, &bytes).map_err(|e| RenderError::io(path, e))
}

/// The bytes of [`write_exr`]'s file.
pub fn encode_exr(img: &RgbImage, tag: &RenderTag) -> std::result::Result<Vec<u8>, String> {
    encode(img, Some(tag))
}

/// An EXR without a render tag: not a render, so `merge` refuses it (a variance image).
pub fn encode_untagged_exr(img: &RgbImage) -> std::result::Result<Vec<u8>, String> {
    encode(img, None)
}

fn encode(img: &RgbImage, tag: Option<&RenderTag>) -> std::result::Result<Vec<u8>, String> {
    let w = img.width;
    let channels = SpecificChannels::rgb(|pos: Vec2<usize>| {
        let p = img.pixels[pos.y() * w + pos.x()];
        (p[0], p[1], p[2])
    });
    let mut attrs = LayerAttributes::default();
    if let Some(tag) = tag {
        let mut text = format!("spp={} scene={:016x}", tag.spp, tag.scene_hash);
        if let Some(v) = tag.view_hash {
            text += &format!(" view={v:016x}");
        }
        let digests = &tag.unknown_digests;
        match (tag.seeds.as_slice(), tag.partial) {
            ([], false) if digests.is_empty() => {}
            ([seed], false) if digests.is_empty() => text += &format!(" seed={seed}"),
            (many, partial) => {
                let mut list: Vec<String> = many.iter().map(u64::to_string).collect();
                list.extend(digests.iter().map(|d| format!("?{d:016x}")));
                if partial && digests.is_empty() {
                    list.push("?".into());
                }
                text += &format!(" seeds={}", list.join(","));
            }
        }
        attrs.other.insert(
            Text::from(ATTR_TAG),
            AttributeValue::Text(Text::from(text.as_str())),
        );
    }
    let layer = Layer::new(
        Vec2(img.width, img.height),
        attrs,
        Encoding::SMALL_LOSSLESS,
        channels,
    );
    let image = Image::from_layer(layer);
    let mut buf = Cursor::new(Vec::new());
    image
        .write()
        .to_buffered(&mut buf)
        .map_err(|e| format!("cannot encode EXR: {e}"))?;
    Ok(buf.into_inner())
}

/// Largest image `read_exr` accepts: the largest render a scene may ask for (16,384², 2^28
/// pixels, 3.2 GB as f32 RGB), which `merge` and `bench error` must read back. The reader
/// allocates the pixels from the header's size before it reads any data, so a corrupt or
/// hostile header must be refused first.
pub const MAX_EXR_PIXELS: usize =
    crate::scene::MAX_IMAGE_SIDE as usize * crate::scene::MAX_IMAGE_SIDE as usize;

/// Largest environment map (`read_exr_at_most`): 2^26 pixels, a 16,384 × 4,096 lat-long map.
pub const MAX_ENV_PIXELS: usize = 1 << 26;

/// Reads an RGB EXR and, if present, its render tag.
pub fn read_exr(path: &Path) -> std::result::Result<(RgbImage, Option<RenderTag>), RenderError> {
    read_exr_at_most(path, MAX_EXR_PIXELS)
}

/// [`read_exr`] of an image of at most `max_pixels`.
pub fn read_exr_at_most(
    path: &Path,
    max_pixels: usize,
) -> std::result::Result<(RgbImage, Option<RenderTag>), RenderError> {
    scatter_sim::output::check_input(path)
        .map_err(|e| RenderError::Image(format!("{}: cannot read EXR: {e}", path.display())))?;
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| {
        // exr's word for an empty file is "reference to missing bytes".
        let what = match std::fs::metadata(path) {
            Ok(m) if m.len() == 0 => "the file is empty".to_string(),
            _ => e.to_string(),
        };
        RenderError::Image(format!("{}: cannot read EXR: {what}", path.display()))
    })?;
    check_headers(path, &meta, max_pixels)?;
    let image = read_rgb_pixels(path)?;
    let tag = tag_of(path, &image.layer_data.attributes.other)?;
    let (pixels, written) = image.layer_data.channel_data.pixels;
    if let Some(i) = written.iter().position(|&w| !w) {
        return Err(RenderError::Image(format!(
            "{}: damaged EXR: row {} holds no pixels (a block is missing)",
            path.display(),
            i / pixels.width.max(1)
        )));
    }
    Ok((pixels, tag))
}

/// Refuses, before any pixel is allocated, a header whose image is larger than
/// `max_pixels` or than the memory left, and a file with no RGB part.
fn check_headers(
    path: &Path,
    meta: &exr::meta::MetaData,
    max_pixels: usize,
) -> std::result::Result<(), RenderError> {
    for h in meta.headers.iter() {
        let (w, ht) = (h.layer_size.width(), h.layer_size.height());
        if w.checked_mul(ht).is_none_or(|n| n > max_pixels) {
            return Err(RenderError::Image(format!(
                "{}: the EXR header declares {w} x {ht} pixels: allowed at most {max_pixels}",
                path.display()
            )));
        }
        // The pixels and the written-or-not flags are allocated from the header before
        // any data is read (up to 3.5 GB at 16,384²): a failed allocation would abort,
        // so the space is reserved and given back first, as for a render's buffers.
        if !crate::render::reservable((w * ht * 14) as u64) {
            return Err(RenderError::Image(format!(
                "{}: a {w} x {ht} image needs about {:.1} GB of memory, which could not be \
                 allocated",
                path.display(),
                (w * ht * 14) as f64 / 1e9
            )));
        }
    }
    // exr's own error for a grey (Y) or single-channel image names no channel ("no layer
    // in the image matched your specified requirements").
    let rgb = |h: &exr::meta::header::Header| {
        ["R", "G", "B"]
            .iter()
            .all(|c| h.channels.list.iter().any(|ch| ch.name == **c))
    };
    if !meta.headers.iter().any(rgb) {
        let found: Vec<String> = meta
            .headers
            .iter()
            .flat_map(|h| h.channels.list.iter().map(|ch| ch.name.to_string()))
            .collect();
        return Err(RenderError::Image(format!(
            "{}: no part of the file has channels named R, G and B (found {}): stcvae reads \
             the unlayered RGB channels it writes",
            path.display(),
            if found.is_empty() {
                "none".to_string()
            } else {
                found.join(", ")
            }
        )));
    }
    Ok(())
}

/// An RGB EXR read with, for each pixel, whether the file wrote it.
type RgbPixelsImage = PixelImage<(RgbImage, Vec<bool>), RgbChannels>;

/// The RGB pixels of the file's first valid layer, with their written-or-not flags.
fn read_rgb_pixels(path: &Path) -> std::result::Result<RgbPixelsImage, RenderError> {
    read()
        .no_deep_data()
        .largest_resolution_level()
        .specific_channels()
        .required("R")
        .required("G")
        .required("B")
        .collect_pixels(
            // With each pixel, whether the file wrote it: exr fills in nothing for a
            // block that a damaged offset table or a repeated block position skips, and
            // such rows read as 0 (a merge took them for black pixels).
            |size: Vec2<usize>, _| {
                let img = RgbImage::new(size.width(), size.height());
                let written = vec![false; img.pixels.len()];
                (img, written)
            },
            |(img, written): &mut (RgbImage, Vec<bool>),
             pos: Vec2<usize>,
             (r, g, b): (f32, f32, f32)| {
                let i = pos.y() * img.width + pos.x();
                img.pixels[i] = [r, g, b];
                written[i] = true;
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| {
            // The header was read before (`check_headers`), so the pixel blocks or their
            // offset table are at fault; exr's own words ("Invalid argument (os error
            // 22)" for an offset past the end) do not say so.
            RenderError::Image(format!(
                "{}: cannot read the EXR's pixels (a damaged or cut-short file?): {e}",
                path.display()
            ))
        })
}

/// The render tag among a file's attributes (`ATTR_TAG`, or the three attributes of older
/// files); None for a file without one.
fn tag_of(
    path: &Path,
    other: &HashMap<Text, AttributeValue>,
) -> std::result::Result<Option<RenderTag>, RenderError> {
    let text = |k: &str| match other.get(&Text::from(k)) {
        Some(AttributeValue::Text(t)) => Some(t.to_string()),
        _ => None,
    };
    // The tag's fields and the attribute each came from: `ATTR_TAG`, or the three
    // attributes of older files.
    let tagged = text(ATTR_TAG);
    let bad = |attr: &str, v: &str| {
        RenderError::Image(format!("{}: bad {attr} attribute `{v}`", path.display()))
    };
    let (names, [spp, scene, seed, view]) = match &tagged {
        // One render's `seed`, or a merge's `seeds` (a comma-separated list).
        Some(t) => (
            [ATTR_TAG; 3],
            parse_tag_text(t).ok_or_else(|| bad(ATTR_TAG, t))?,
        ),
        None => (
            [ATTR_SPP, ATTR_SCENE, ATTR_SEED],
            [text(ATTR_SPP), text(ATTR_SCENE), text(ATTR_SEED), None],
        ),
    };
    Ok(match (spp, scene) {
        (Some(s), Some(h)) => {
            let (mut seeds, mut partial, mut digests) = (Vec::new(), false, Vec::new());
            let v = seed.as_deref().unwrap_or_default();
            for x in seed.as_deref().map(|v| v.split(',')).into_iter().flatten() {
                match x.strip_prefix('?') {
                    Some("") if !partial => partial = true,
                    Some(hex) if hex.len() == 16 => {
                        let d = u64::from_str_radix(hex, 16).map_err(|_| bad(names[2], v))?;
                        if digests.contains(&d) {
                            return Err(bad(names[2], v));
                        }
                        digests.push(d);
                        partial = true;
                    }
                    Some(_) => return Err(bad(names[2], v)),
                    None => {
                        let s: u64 = x.parse().map_err(|_| bad(names[2], v))?;
                        if seeds.contains(&s) {
                            return Err(bad(names[2], v));
                        }
                        seeds.push(s);
                    }
                }
            }
            Some(RenderTag {
                spp: s.parse().map_err(|_| bad(names[0], &s))?,
                scene_hash: u64::from_str_radix(&h, 16).map_err(|_| bad(names[1], &h))?,
                seeds,
                partial,
                unknown_digests: digests,
                view_hash: view
                    .map(|v| match u64::from_str_radix(&v, 16) {
                        Ok(x) if v.len() == 16 => Ok(x),
                        _ => Err(bad(names[1], &v)),
                    })
                    .transpose()?,
            })
        }
        // A tag attribute without its spp and scene is damaged; an old file without the
        // pair simply has no tag.
        _ => match tagged {
            Some(t) => return Err(bad(ATTR_TAG, &t)),
            None => None,
        },
    })
}

/// sRGB transfer function of a linear value in [0, 1].
fn srgb(x: f32) -> f32 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// An 8-bit sRGB preview at the given exposure (values clipped at 1), as a PNG file's
/// bytes (written with the image's other files as one set).
pub fn encode_png(img: &RgbImage, exposure: f32) -> std::result::Result<Vec<u8>, String> {
    encode_png_levels(img, |v| {
        let v = if v.is_finite() { v * exposure } else { 0.0 };
        srgb(v.clamp(0.0, 1.0))
    })
}

/// A diagram whose values in [0, 1] are the grey levels themselves (0.5 → 128), as a PNG
/// file's bytes: for maps whose grey encodes a number (z-scores, work counts), which the
/// sRGB curve of a render's preview would bend (z = 0 came out 188, not 128, and z = ±3
/// as 240 and 99).
pub fn encode_png_linear(img: &RgbImage) -> std::result::Result<Vec<u8>, String> {
    encode_png_levels(img, |v| {
        if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        }
    })
}

fn encode_png_levels(
    img: &RgbImage,
    level: impl Fn(f32) -> f32,
) -> std::result::Result<Vec<u8>, String> {
    let data: Vec<u8> = img
        .pixels
        .iter()
        .flat_map(|p| p.map(|v| (level(v) * 255.0 + 0.5) as u8))
        .collect();
    let mut buf = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut buf, img.width as u32, img.height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc
            .write_header()
            .map_err(|e| format!("cannot encode PNG: {e}"))?;
        wr.write_image_data(&data)
            .map_err(|e| format!("cannot encode PNG: {e}"))?;
    }
    Ok(buf)
}

/// Averages renders of the same scene weighted by their spp. Refuses images of
/// different scenes or sizes, images without a render tag, and two renders of one seed.
pub fn merge_exrs(paths: &[&Path]) -> std::result::Result<(RgbImage, RenderTag), RenderError> {
    let mut acc: Option<(RgbImage, RenderTag, Vec<[f64; 3]>)> = None;
    let mut seen: Vec<Seen> = Vec::new();
    for &p in paths {
        let (img, tag) = read_exr(p)?;
        let digest = img.pixel_digest();
        let seeds = tag.as_ref().map_or_else(Vec::new, |t| t.seeds.clone());
        let unknown = tag.as_ref().is_none_or(RenderTag::some_unknown);
        let scene = tag.as_ref().map(|t| t.scene_hash);
        let mut unknown_digests = tag
            .as_ref()
            .map_or_else(Vec::new, |t| t.unknown_digests.clone());
        if seeds.is_empty()
            && let Some(d) = digest
            && !unknown_digests.contains(&d)
        {
            unknown_digests.push(d);
        }
        let input = Seen {
            scene,
            seeds,
            unknown,
            digest,
            unknown_digests: unknown_digests.clone(),
            path: p,
        };
        refuse_shared_samples(&seen, &input)?;
        seen.push(input);
        let tag = merge_tag(p, tag)?;
        check_merge_pixels(p, &img)?;
        accumulate(&mut acc, paths[0], p, img, tag, unknown_digests)?;
    }
    let (mut img, tag, sum) =
        acc.ok_or_else(|| RenderError::Image("merge: no input images".into()))?;
    for (px, s) in img.pixels.iter_mut().zip(sum) {
        *px = s.map(|v| (v / tag.spp as f64) as f32);
    }
    Ok((img, tag))
}

/// An input of `merge_exrs` as far as shared samples go. Renders with the same seed share
/// their samples (a copy, or a seed rendered again at another spp), which would count
/// twice. Files without a recorded seed (written before it was) are compared by their
/// pixels instead, unless the image is constant (an object out of view or unlit: every
/// seed gives the same pixels). Renders of other scenes are refused by `accumulate` with
/// that reason.
struct Seen<'a> {
    scene: Option<u64>,
    seeds: Vec<u64>,
    unknown: bool,
    digest: Option<u64>,
    /// The digests of the renders of unknown seed it holds: its own where it is one
    /// (no seed at all), those its tag records where it is a merge of some.
    unknown_digests: Vec<u64>,
    path: &'a Path,
}

/// Refuses `input` where it shares samples with a render read before it.
fn refuse_shared_samples(seen: &[Seen], input: &Seen) -> std::result::Result<(), RenderError> {
    let Seen {
        scene,
        seeds,
        unknown,
        digest,
        unknown_digests,
        path: p,
    } = input;
    let (scene, unknown, digest) = (*scene, *unknown, *digest);
    let shared = |o: &Seen| seeds.iter().copied().find(|s| o.seeds.contains(s));
    // A seed in common shares samples; where either holds renders of unknown seed,
    // equal pixels are the only sign left: the images' own, or those recorded of the
    // renders of unknown seed a merge holds.
    let twin = seen.iter().find(|o| {
        o.scene == scene
            && (shared(o).is_some()
                || ((unknown || o.unknown) && digest.is_some() && o.digest == digest)
                || unknown_digests
                    .iter()
                    .any(|d| o.unknown_digests.contains(d)))
    });
    if let Some(o) = twin {
        // Known by a seed, by equal pixels, or by a recorded render of unknown seed
        // that both hold (two merges sharing an input).
        let common = unknown_digests
            .iter()
            .find(|d| o.unknown_digests.contains(d));
        let same_pixels = digest.is_some() && o.digest == digest;
        return Err(RenderError::Image(match (shared(o), common) {
            (None, Some(d)) if !same_pixels => format!(
                "{}: holds a render of unknown seed that {} holds too (pixels with digest \
                 {d:016x}): its samples would count twice; merge images with no render in \
                 common",
                p.display(),
                o.path.display()
            ),
            (Some(s), _) => format!(
                "{}: shares seed {s} with {}: rendered on one device, its samples are in \
                 both and would count twice (the tag does not record the device, and the \
                 CPU and GPU draw different streams from one seed, so renders of one seed \
                 on the two are refused too); merge renders of different seeds",
                p.display(),
                o.path.display(),
            ),
            (None, _) => format!(
                "{}: holds the same render as {} (equal pixels): its samples would count \
                 twice; merge renders of different seeds",
                p.display(),
                o.path.display(),
            ),
        }));
    }
    Ok(())
}

/// The render tag `merge` weights an input by: present, and of at least one sample.
fn merge_tag(p: &Path, tag: Option<RenderTag>) -> std::result::Result<RenderTag, RenderError> {
    let tag = tag.ok_or_else(|| {
        // `merge *.exr` picks up `render --variance`'s images too.
        let hint = if p.to_string_lossy().ends_with(".var.exr") {
            " (a variance image of `render --variance`? leave it out)"
        } else {
            ""
        };
        RenderError::Image(format!(
            "{}: no stcvae render tag (spp, scene hash) in the EXR header: not an stcvae \
             render{hint}",
            p.display()
        ))
    })?;
    if tag.spp == 0 {
        return Err(RenderError::Image(format!(
            "{}: the render tag says 0 spp: nothing to weight it by",
            p.display()
        )));
    }
    Ok(tag)
}

/// Refuses an input pixel that is not finite or is negative.
fn check_merge_pixels(p: &Path, img: &RgbImage) -> std::result::Result<(), RenderError> {
    if let Some((x, y)) = img.first_non_finite() {
        return Err(RenderError::Image(format!(
            "{}: pixel ({x}, {y}) is not finite: refusing to spread it into the merge",
            p.display(),
        )));
    }
    // Radiance estimates are never negative; such a pixel means a damaged or foreign
    // file (the environment loader refuses them too).
    if let Some((x, y, _)) = img.first_value(|v| v < 0.0) {
        return Err(RenderError::Image(format!(
            "{}: pixel ({x}, {y}) is negative: a render's pixels are ≥ 0",
            p.display()
        )));
    }
    Ok(())
}

/// Adds one input, weighted by its spp, to the running sum (the first input starts it);
/// refuses one of another scene or size than the first, and an spp total that overflows.
fn accumulate(
    acc: &mut Option<(RgbImage, RenderTag, Vec<[f64; 3]>)>,
    first_path: &Path,
    p: &Path,
    img: RgbImage,
    tag: RenderTag,
    unknown_digests: Vec<u64>,
) -> std::result::Result<(), RenderError> {
    match acc {
        None => {
            let sum = img
                .pixels
                .iter()
                .map(|px| px.map(|v| v as f64 * tag.spp as f64))
                .collect();
            let mut tag = tag;
            tag.partial = tag.some_unknown();
            tag.unknown_digests = unknown_digests;
            *acc = Some((img, tag, sum));
        }
        Some((first, t0, sum)) => {
            if tag.scene_hash != t0.scene_hash {
                return Err(RenderError::Image(format!(
                    "{}: scene hash {:016x} differs from {:016x} of {}: renders of different scenes (or of one scene with another integrator, model or render settings, or by a build of stcvae whose renderer differs) cannot be merged",
                    p.display(),
                    tag.scene_hash,
                    t0.scene_hash,
                    first_path.display()
                )));
            }
            if (img.width, img.height) != (first.width, first.height) {
                return Err(RenderError::Image(format!(
                    "{}: size {}x{} differs from {}x{}",
                    p.display(),
                    img.width,
                    img.height,
                    first.width,
                    first.height
                )));
            }
            for (s, px) in sum.iter_mut().zip(&img.pixels) {
                for c in 0..3 {
                    s[c] += px[c] as f64 * tag.spp as f64;
                }
            }
            t0.spp = t0.spp.checked_add(tag.spp).ok_or_else(|| {
                RenderError::Image(format!("{}: the spp total overflows", p.display()))
            })?;
            // Known seeds are kept whatever else comes in; an input of unknown seed
            // marks the list as partial (a list with it missing would read as whole).
            t0.partial |= tag.some_unknown();
            t0.seeds.extend(&tag.seeds);
            t0.unknown_digests.extend(unknown_digests);
            // Equal scene hashes give equal views; a file written before views were
            // recorded leaves the merge's unknown.
            if tag.view_hash != t0.view_hash {
                t0.view_hash = None;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The 8-bit levels of a PNG file's bytes, as a viewer reads them.
    fn levels(png: Vec<u8>) -> Vec<u8> {
        let mut dec = png::Decoder::new(std::io::Cursor::new(png))
            .read_info()
            .unwrap();
        let mut buf = vec![0; dec.output_buffer_size()];
        dec.next_frame(&mut buf).unwrap();
        buf
    }

    /// A diagram's values are its grey levels (0.5 → 128: a z-map's agreement is
    /// mid-grey), where a render's preview bends them by the sRGB curve (0.5 → 188);
    /// values beyond [0, 1] clip, and a NaN or an infinity is black in both (clipped, +∞
    /// would pass for a bright pixel). The preview's exposure scales the values before the
    /// curve.
    #[test]
    fn diagrams_are_written_without_the_srgb_curve() {
        let mut img = RgbImage::new(3, 2);
        img.pixels = vec![
            [0.0, 0.5, 1.0],
            [0.25, -1.0, 2.0],
            [f32::NAN, 0.75, 0.001],
            [f32::INFINITY, f32::NEG_INFINITY, 0.3],
            [0.4, 0.6, 0.7],
            [0.8, 0.9, 0.95],
        ];
        let linear = levels(encode_png_linear(&img).unwrap());
        let want: Vec<u8> = img
            .pixels
            .iter()
            .flatten()
            .map(|&v| {
                if !v.is_finite() {
                    0
                } else {
                    (v.clamp(0.0, 1.0) * 255.0).round() as u8
                }
            })
            .collect();
        assert_eq!(linear, want);
        let preview = levels(encode_png(&img, 1.0).unwrap());
        assert_eq!((preview[1], linear[1]), (188, 128));
        assert_eq!(
            preview[6..11],
            [0, 225, 3, 0, 0],
            "NaN, 0.75, 0.001, +∞, −∞"
        );
        // The preview is the sRGB curve of exposure × value (IEC 61966-2-1; the levels
        // below computed from it by hand): at exposure 4, 0.25 is white, 0.05 is
        // sRGB(0.2) = 0.4845 → 124, 0.0005 on the curve's linear toe 12.92 × 0.002 → 7,
        // 1 clips; at exposure 0.5, 0.5 is sRGB(0.25) → 137. An exposure that divided
        // would give 71, 29, 0 and 137.
        let mut img = RgbImage::new(2, 1);
        img.pixels = vec![[0.25, 0.05, 0.0005], [1.0, 0.5, 0.0]];
        assert_eq!(
            levels(encode_png(&img, 4.0).unwrap())[..4],
            [255, 124, 7, 255]
        );
        assert_eq!(levels(encode_png(&img, 0.5).unwrap())[4], 137);
    }

    fn image() -> RgbImage {
        let mut img = RgbImage::new(5, 3);
        for (k, p) in img.pixels.iter_mut().enumerate() {
            *p = [k as f32, 0.5 * k as f32, 1.0 / (1.0 + k as f32)];
        }
        img
    }

    /// A grey (Y) or red-only EXR is refused naming the channels it has, instead of exr's
    /// "no layer in the image matched your specified requirements"; a part with some of R,
    /// G and B is not an RGB part (the red-only file passed the check, and exr's own words
    /// for it named no channel).
    #[test]
    fn an_exr_without_rgb_names_its_channels() {
        let dir = tempfile::tempdir().unwrap();
        for (name, channel) in [("grey.exr", "Y"), ("red.exr", "R")] {
            let p = dir.path().join(name);
            let channels = SpecificChannels::build()
                .with_channel(channel)
                .with_pixel_fn(|_| (0.5f32,));
            Image::from_channels((2, 2), channels)
                .write()
                .to_file(&p)
                .unwrap();
            let e = read_exr(&p).unwrap_err().to_string();
            let want = format!(
                "{name}: no part of the file has channels named R, G and B (found {channel})"
            );
            assert!(e.contains(&want), "{e}");
        }
    }

    /// The same image and tag encode to the same bytes every time (with the tag as three
    /// attributes, the exr crate's HashMap wrote them in a different order in most of
    /// these ten encodings), and the tag reads back.
    #[test]
    fn exr_files_are_reproducible_and_keep_their_tag() {
        let img = image();
        let dir = tempfile::tempdir().unwrap();
        // One render's seed, a merge's seeds, none, merges with inputs of unknown seed
        // (constant, or known by their pixels' digests).
        for (seeds, partial, unknown_digests) in [
            (vec![7], false, vec![]),
            (vec![7, 9, 12], false, vec![]),
            (vec![], false, vec![]),
            (vec![7], true, vec![]),
            (vec![], true, vec![]),
            (vec![7], true, vec![0x0123_4567_89ab_cdef, 5]),
            (vec![], true, vec![u64::MAX]),
        ] {
            let tag = RenderTag {
                spp: 96,
                scene_hash: 0x00ab_cdef_0123_4567,
                seeds,
                partial,
                unknown_digests,
                view_hash: partial.then_some(0xfedc_ba98_7654_3210),
            };
            let first = encode_exr(&img, &tag).unwrap();
            for _ in 0..10 {
                assert!(encode_exr(&img, &tag).unwrap() == first, "EXR bytes differ");
            }
            let path = dir.path().join("a.exr");
            std::fs::write(&path, &first).unwrap();
            let (back, read) = read_exr(&path).unwrap();
            assert_eq!(back, img);
            assert_eq!(read.unwrap(), tag);
        }
    }

    /// Tags a render never writes are refused, naming the file: an unknown or repeated key,
    /// both seed forms, a repeated seed (merge's bookkeeping of seeds would trust them).
    #[test]
    fn damaged_tags_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let good = RenderTag {
            spp: 4,
            scene_hash: 0xab,
            seeds: vec![2],
            partial: false,
            unknown_digests: Vec::new(),
            view_hash: None,
        };
        let bytes = encode_exr(&image(), &good).unwrap();
        let from = b"spp=4 scene=00000000000000ab seed=2";
        let at = bytes
            .windows(from.len())
            .position(|w| w == from)
            .expect("the tag text is in the header");
        // Same length as the original, so the header's sizes stay right.
        for bad in [
            "spp=4 scene=00000000000000ab segd=2",
            "spp=4 scene=00000000000000ab spp=22",
            "spp=4 scene=00000000000000ab ??????",
            "spp=4 scene=00000000000000ab foo=b1",
            "spp=4 scene=000000000ab seeds=22,22",
            "spp=4 scene=0000ab seed=1 seeds=2,3",
            "spp=4 scene=00000000000000ab view=2",
        ] {
            assert_eq!(bad.len(), from.len(), "{bad}");
            let mut b = bytes.clone();
            b[at..at + from.len()].copy_from_slice(bad.as_bytes());
            let path = dir.path().join("bad.exr");
            std::fs::write(&path, &b).unwrap();
            let e = read_exr(&path).unwrap_err().to_string();
            assert!(e.contains("bad.exr: bad stcvaeTag attribute"), "{bad}: {e}");
        }
    }

    /// A file whose second block claims the first block's rows (a damaged offset table or
    /// block header) leaves rows unwritten: refused, naming the first of them, instead of
    /// reading them as 0. 8 × 40 pixels in ZIP blocks of 16 rows: three blocks, whose
    /// offsets follow the header (the table is where a u64 equals its own position + 24).
    #[test]
    fn an_exr_with_a_missing_block_is_refused() {
        let mut img = RgbImage::new(8, 40);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = [1.0 + i as f32, 2.0, 3.0];
        }
        let tag = RenderTag {
            spp: 3,
            scene_hash: 1,
            seeds: vec![1],
            partial: false,
            unknown_digests: Vec::new(),
            view_hash: None,
        };
        let bytes = encode_exr(&img, &tag).unwrap();
        let u64_at = |p: usize| u64::from_le_bytes(bytes[p..p + 8].try_into().unwrap());
        let table = (0..bytes.len() - 24)
            .find(|&p| u64_at(p) == p as u64 + 24)
            .expect("an offset table of three blocks");
        let second = u64_at(table + 8) as usize;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.exr");
        std::fs::write(&path, &bytes).unwrap();
        assert_eq!(read_exr(&path).unwrap().0, img);
        let mut damaged = bytes.clone();
        damaged[second..second + 4].copy_from_slice(&0i32.to_le_bytes());
        std::fs::write(&path, &damaged).unwrap();
        let e = read_exr(&path).unwrap_err().to_string();
        assert!(e.contains("damaged EXR: row 16 holds no pixels"), "{e}");
        // A first offset far beyond the file's end: exr said only "Invalid argument (os
        // error 22)"; the message says the pixels could not be read.
        let mut beyond = bytes.clone();
        beyond[table..table + 8].copy_from_slice(&(1u64 << 62).to_le_bytes());
        std::fs::write(&path, &beyond).unwrap();
        let e = read_exr(&path).unwrap_err().to_string();
        assert!(
            e.contains("a.exr: cannot read the EXR's pixels (a damaged or cut-short file?)"),
            "{e}"
        );
    }

    /// A render with a NaN, infinite or negative pixel is refused by name and position, not
    /// averaged into the merge.
    #[test]
    fn merges_refuse_non_finite_pixels_by_position() {
        let dir = tempfile::tempdir().unwrap();
        let good = image();
        assert_eq!(good.first_non_finite(), None);
        for (bad_value, why) in [
            (f32::NAN, "is not finite"),
            (f32::INFINITY, "is not finite"),
            (-1.0, "is negative"),
        ] {
            let mut bad = image();
            bad.pixels[5 + 3][1] = bad_value; // (x, y) = (3, 1) in a 5-wide image
            if bad_value.is_finite() {
                assert_eq!(bad.first_non_finite(), None);
            } else {
                assert_eq!(bad.first_non_finite(), Some((3, 1)));
            }
            let paths = [("good.exr", &good, 1), ("bad.exr", &bad, 2)]
                .map(|(name, img, seed)| write_render(dir.path(), name, img, seed));
            let e = merge_exrs(&[&paths[0], &paths[1]]).unwrap_err().to_string();
            assert!(
                e.contains("bad.exr") && e.contains(&format!("pixel (3, 1) {why}")),
                "{e}"
            );
        }
    }

    /// `img` written into `dir` as a render of 4 spp of scene hash 1 with seed `seed`.
    fn write_render(
        dir: &std::path::Path,
        name: &str,
        img: &RgbImage,
        seed: u64,
    ) -> std::path::PathBuf {
        write_tagged(dir, name, img, vec![seed])
    }

    /// `img` written into `dir` as a render of 4 spp of scene hash 1 with `seeds` (none:
    /// a render of an earlier version, which recorded no seed).
    fn write_tagged(
        dir: &std::path::Path,
        name: &str,
        img: &RgbImage,
        seeds: Vec<u64>,
    ) -> std::path::PathBuf {
        let tag = RenderTag {
            spp: 4,
            scene_hash: 1,
            seeds,
            partial: false,
            unknown_digests: Vec::new(),
            view_hash: None,
        };
        let path = dir.join(name);
        std::fs::write(&path, encode_exr(img, &tag).unwrap()).unwrap();
        path
    }

    /// Renders of one scene hash but different sizes are refused, naming both sizes: a
    /// 4×2 and a 4×3 image (distinct seeds) differ in height only, and were summed pixel by
    /// pixel over the first 8 as if the same image; a 4×2 and a 2×4 hold as many pixels.
    #[test]
    fn merges_refuse_images_of_another_shape() {
        let dir = tempfile::tempdir().unwrap();
        for ((w, h), want) in [((4, 3), "size 4x3 differs"), ((2, 4), "size 2x4 differs")] {
            let paths = [("wide.exr", 4, 2, 1), ("other.exr", w, h, 2)].map(
                |(name, width, height, seed)| {
                    let mut img = RgbImage::new(width, height);
                    for (k, p) in img.pixels.iter_mut().enumerate() {
                        *p = [k as f32; 3];
                    }
                    write_render(dir.path(), name, &img, seed)
                },
            );
            let e = merge_exrs(&[&paths[0], &paths[1]]).unwrap_err().to_string();
            assert!(e.contains(&format!("other.exr: {want} from 4x2")), "{e}");
        }
    }

    /// `img` written to `path` as an EXR whose header holds the text attributes `attrs`
    /// (tags as other versions, or damage, would write them).
    fn exr_with_attrs(path: &Path, img: &RgbImage, attrs: &[(&str, &str)]) {
        let w = img.width;
        let channels = SpecificChannels::rgb(|pos: Vec2<usize>| {
            let p = img.pixels[pos.y() * w + pos.x()];
            (p[0], p[1], p[2])
        });
        let mut layer_attrs = LayerAttributes::default();
        for &(k, v) in attrs {
            layer_attrs
                .other
                .insert(Text::from(k), AttributeValue::Text(Text::from(v)));
        }
        let layer = Layer::new(
            Vec2(img.width, img.height),
            layer_attrs,
            Encoding::SMALL_LOSSLESS,
            channels,
        );
        Image::from_layer(layer).write().to_file(path).unwrap();
    }

    /// Files written with the three attributes of earlier versions still give their tag,
    /// with their seed where they have one.
    #[test]
    fn exr_files_of_earlier_versions_keep_their_tag() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.exr");
        let old = [(ATTR_SPP, "12"), (ATTR_SCENE, "00000000000000ff")];
        for (attrs, seeds) in [
            (&old[..], vec![]),
            (&[old[0], old[1], (ATTR_SEED, "5")][..], vec![5]),
        ] {
            exr_with_attrs(&path, &image(), attrs);
            let tag = read_exr(&path).unwrap().1.unwrap();
            assert_eq!(
                (tag.spp, tag.scene_hash, tag.seeds, tag.partial),
                (12, 255, seeds, false)
            );
        }
    }

    /// A tag may name a render of unknown seed once (`?`, a constant image) or by its
    /// pixels' digest once each: repeating either is refused as the repeated seed is, since
    /// `merge` would count that render twice. A digest beside a seed reads back.
    #[test]
    fn tags_repeating_a_render_of_unknown_seed_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let ok = dir.path().join("ok.exr");
        let tag = |seeds: &str| format!("spp=4 scene=00000000000000ab seeds={seeds}");
        exr_with_attrs(&ok, &image(), &[(ATTR_TAG, &tag("7,?000000000000000a"))]);
        let read = read_exr(&ok).unwrap().1.unwrap();
        assert_eq!(
            (read.seeds, read.partial, read.unknown_digests),
            (vec![7], true, vec![10])
        );
        for bad in ["?000000000000000a,?000000000000000a", "7,?,?"] {
            let p = dir.path().join("rep.exr");
            exr_with_attrs(&p, &image(), &[(ATTR_TAG, &tag(bad))]);
            let e = read_exr(&p).unwrap_err().to_string();
            assert!(e.contains("rep.exr: bad stcvaeTag attribute"), "{bad}: {e}");
        }
    }

    /// An image of exactly the pixel limit is read; one pixel fewer allowed refuses it.
    #[test]
    fn an_image_of_exactly_the_pixel_limit_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_render(dir.path(), "a.exr", &image(), 1);
        let (w, h) = (image().width, image().height);
        let n = w * h;
        assert_eq!(read_exr_at_most(&path, n).unwrap().0, image());
        let e = read_exr_at_most(&path, n - 1).unwrap_err().to_string();
        let want = format!(
            "a.exr: the EXR header declares {w} x {h} pixels: allowed at most {}",
            n - 1
        );
        assert!(e.contains(&want), "{e}");
    }

    /// A seedless copy of a seeded render (its pixels equal) is refused whichever comes
    /// first: its samples would count twice.
    #[test]
    fn a_seedless_copy_of_a_seeded_render_is_refused_in_either_order() {
        let dir = tempfile::tempdir().unwrap();
        let img = image();
        let seeded = write_render(dir.path(), "a.exr", &img, 1);
        let copy = write_tagged(dir.path(), "old.exr", &img, Vec::new());
        for (first, second) in [(&seeded, &copy), (&copy, &seeded)] {
            let e = merge_exrs(&[first.as_path(), second.as_path()])
                .unwrap_err()
                .to_string();
            let name = second.file_name().unwrap().to_str().unwrap();
            assert!(
                e.contains(&format!("{name}: holds the same render as")),
                "{e}"
            );
        }
    }

    /// A merge whose first input is a seedless constant image is partial, and is written
    /// so ("seeds=1,?"): written "seed=1", it would claim to be the whole render of seed 1.
    #[test]
    fn a_merge_led_by_a_seedless_constant_image_stays_partial() {
        let dir = tempfile::tempdir().unwrap();
        let mut flat = RgbImage::new(image().width, image().height);
        flat.pixels.fill([0.5; 3]);
        let c = write_tagged(dir.path(), "c.exr", &flat, Vec::new());
        let a = write_render(dir.path(), "a.exr", &image(), 1);
        let (img, tag) = merge_exrs(&[c.as_path(), a.as_path()]).unwrap();
        assert_eq!((tag.spp, &tag.seeds, tag.partial), (8, &vec![1], true));
        let m = dir.path().join("m.exr");
        std::fs::write(&m, encode_exr(&img, &tag).unwrap()).unwrap();
        let back = read_exr(&m).unwrap().1.unwrap();
        assert_eq!((back.seeds, back.partial), (vec![1], true));
    }

    /// The preview's sRGB curve leaves its linear toe (12.92·v) for the power segment
    /// (1.055·v^(1/2.4) − 0.055) at v = 0.0031308, IEC 61966-2-1's encoding threshold
    /// (0.04045, the decoding one, is in sRGB values). Linear 0.01, 0.02 and 0.03 lie on
    /// the power segment: 0.0998, 0.1517, 0.1897 → levels 25, 39, 48 (v·255 + 0.5
    /// truncated; computed by hand, each ≥ 0.03 of a level from a rounding edge). On the
    /// toe, as with the thresholds confused, they would be 33, 66 and 99. The other
    /// preview test's values lie where both thresholds agree (0.002 on the toe, ≥ 0.2 on
    /// the power segment).
    #[test]
    fn the_preview_curve_breaks_at_the_encoding_threshold() {
        let mut img = RgbImage::new(1, 1);
        img.pixels = vec![[0.01, 0.02, 0.03]];
        assert_eq!(levels(encode_png(&img, 1.0).unwrap())[..3], [25, 39, 48]);
    }
}
