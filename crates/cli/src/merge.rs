//! `stcvae merge`: join dataset shards (or any datasets), or average renders (.exr) of one
//! scene.

use std::fs::File;
use std::hash::{DefaultHasher, Hasher};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow, bail};
use scatter_sim::dataset::{self, DatasetReader, Header, Piece};
use scatter_sim::output::AtomicFile;

use crate::progress;

#[derive(clap::Args)]
#[command(
    after_help = "Renders: `stcvae merge a.exr b.exr --out m` averages renders of one scene \
    (different seeds) weighted by the spp in their headers into m.exr, m.png and m.json, and \
    refuses renders of different scenes and samples given twice (one seed in two inputs, a merged \
    image's included).\n\nDatasets: shards of one run (same seed, sampler and size) are put in walk order \
    whatever order they are given in, so `stcvae merge data/train-*.bin --out data/train.bin` \
    reproduces the unsharded run row for row. Other inputs are concatenated in the order \
    given. Binary inputs can be written as CSV (--out x.csv); CSV inputs are joined as text, \
    each row checked as a binary row is."
)]
pub struct Args {
    /// Input files: renders (.exr, from `stcvae render`), or binary datasets, or CSV files;
    /// one kind per call.
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Output: for renders the stem of OUT.exr, OUT.png and OUT.json; for datasets the file
    /// (.csv for CSV, else binary).
    #[arg(long)]
    out: PathBuf,
    /// Renders only: exposure of the merged PNG preview, > 0 (the EXR is linear and
    /// unscaled). Default: the exposure the inputs' reports (their .json) record, where
    /// they all record the same one, else 1.
    #[arg(long, allow_negative_numbers = true, value_parser = crate::render::parse_exposure)]
    exposure: Option<f32>,
}

/// Refuses an input given twice (it would count twice) and outputs that overwrite an input.
fn check_paths(inputs: &[PathBuf], outputs: &[PathBuf]) -> Result<()> {
    let ids: Vec<PathBuf> = inputs.iter().map(|p| crate::paths::identity(p)).collect();
    for (i, id) in ids.iter().enumerate() {
        if let Some(j) = ids[..i].iter().position(|x| x == id) {
            bail!(
                "{} and {} are the same file: each input may be given once",
                inputs[j].display(),
                inputs[i].display()
            );
        }
    }
    for o in outputs {
        if let Some(i) = ids.iter().position(|x| *x == crate::paths::identity(o)) {
            bail!(
                "--out would overwrite the input {}: choose another output name",
                inputs[i].display()
            );
        }
    }
    Ok(())
}

pub fn run(a: Args) -> Result<()> {
    // A render's other outputs, given by a slip (`merge r1.png r2.png`): said so, rather
    // than read as datasets with bad magic bytes.
    if let Some((p, ext)) = a.inputs.iter().find_map(|p| {
        let ext = p.extension()?.to_str()?.to_ascii_lowercase();
        ["png", "json"].contains(&ext.as_str()).then_some((p, ext))
    }) {
        bail!(
            "{}: merge reads a render's .exr (the .{ext} beside it is {}); give {}",
            p.display(),
            if ext == "png" {
                "an 8-bit preview"
            } else {
                "its report"
            },
            p.with_extension("exr").display()
        );
    }
    let is_exr = |p: &PathBuf| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    let exr_inputs = a.inputs.iter().filter(|p| is_exr(p)).count();
    if exr_inputs == a.inputs.len() {
        check_paths(
            &a.inputs,
            &[
                image_out(&a.out, "exr"),
                image_out(&a.out, "png"),
                image_out(&a.out, "json"),
            ],
        )?;
        return merge_images(&a);
    } else if exr_inputs > 0 {
        let other = a
            .inputs
            .iter()
            .find(|p| !is_exr(p))
            .expect("a non-.exr input");
        bail!(
            "mixed inputs: {} is not a render (.exr); merge either renders or datasets \
             (.bin, .csv), not both",
            other.display()
        );
    }
    if a.exposure.is_some() {
        bail!("--exposure applies to renders (.exr) only: a dataset has no preview");
    }
    // A dataset written over a render's file (say `--out run.exr` by a slip), a config or
    // a model would replace it with binary rows.
    crate::paths::check_dataset_out(
        &a.out,
        "a dataset, as its inputs are (.csv for text, any other name binary, e.g. .bin)",
    )?;
    check_paths(&a.inputs, std::slice::from_ref(&a.out))?;
    crate::check_out("--out", &a.out)?;
    let csv_inputs = a.inputs.iter().filter(|p| dataset::is_csv(p)).count();
    match csv_inputs {
        0 => merge_binary(&a),
        n if n == a.inputs.len() => merge_csv(&a),
        _ => bail!("mixed inputs: merge either binary datasets or CSV files, not both"),
    }
}

/// The stem of an image output (`render`, `merge`): an `.exr`, `.png` or `.json` the user
/// typed is dropped, anything else (`run.v2`) is kept whole.
pub(crate) fn out_stem(out: &Path) -> PathBuf {
    let known = out.extension().is_some_and(|e| {
        ["exr", "png", "json"]
            .iter()
            .any(|k| e.eq_ignore_ascii_case(k))
    });
    if known {
        out.with_extension("")
    } else {
        out.to_path_buf()
    }
}

/// Whether OUT.var.exr is some other image than a variance image of OUT: a render,
/// montage or map the user named OUT.var has OUT.var.png beside it, a render its tag
/// (variance images are untagged and have no PNG). Such a file is neither removed as
/// stale nor overwritten by `render --variance`.
pub(crate) fn foreign_var_exr(out: &Path) -> bool {
    let var = image_out(out, "var.exr");
    var.is_file()
        && (image_out(out, "var.png").exists()
            || !matches!(render_gpu::image_io::read_exr(&var), Ok((_, None))))
}

/// OUT.ext for an image output: [`out_stem`] plus the extension.
pub(crate) fn image_out(out: &Path, ext: &str) -> PathBuf {
    let mut s = out_stem(out).into_os_string();
    s.push(".");
    s.push(ext);
    PathBuf::from(s)
}

/// Writes OUT.exr (linear, tagged), OUT.png (preview at `exposure`) and, given `json`,
/// OUT.json as one set ([`scatter_sim::output::write_atomic_set`]): a failure never leaves
/// a new image beside an old report. Creates OUT's folder. Every rendered image stcvae
/// writes goes through here (render, merge, experiments) but the work maps of `experiment
/// complexity`, whose EXR and PNG hold different images (`experiment::measure::save_map`),
/// and `bench render --save`'s six files a density (`bench_render::save_images`), each
/// written as one atomic set of its own.
pub(crate) fn write_image_set(
    out: &Path,
    img: &render_gpu::image_io::RgbImage,
    tag: &render_gpu::image_io::RenderTag,
    exposure: f32,
    json: Option<&[u8]>,
) -> Result<()> {
    write_image_set_with(out, img, Some(tag), exposure, json, None, &[])
}

/// [`write_image_set`] with, given `variance`, OUT.var.exr in the same set (untagged:
/// `merge` refuses it as a render). Without `tag` OUT.exr is untagged too: a picture
/// made from renders (a montage, a map), not a render that `merge` could average.
/// `inputs`: the files the command read (as `paths::check_not_input` takes them), which
/// an OUT.var.exr that looks stale is not removed as.
pub(crate) fn write_image_set_with(
    out: &Path,
    img: &render_gpu::image_io::RgbImage,
    tag: Option<&render_gpu::image_io::RenderTag>,
    exposure: f32,
    json: Option<&[u8]>,
    variance: Option<&render_gpu::image_io::RgbImage>,
    inputs: &[(String, PathBuf)],
) -> Result<()> {
    let (exr, png, js) = (
        image_out(out, "exr"),
        image_out(out, "png"),
        image_out(out, "json"),
    );
    // No folder made here: the set's writer makes the missing ones and removes them again
    // if the set fails (one made up front stayed behind, empty).
    let exr_bytes = match tag {
        Some(tag) => render_gpu::image_io::encode_exr(img, tag),
        None => render_gpu::image_io::encode_untagged_exr(img),
    }
    .map_err(|e| anyhow!("{}: {e}", exr.display()))?;
    let png_bytes = render_gpu::image_io::encode_png(img, exposure)
        .map_err(|e| anyhow!("{}: {e}", png.display()))?;
    let var = image_out(out, "var.exr");
    let var_bytes = variance
        .map(render_gpu::image_io::encode_untagged_exr)
        .transpose()
        .map_err(|e| anyhow!("{}: {e}", var.display()))?;
    let mut files = vec![(exr.as_path(), exr_bytes.as_slice()), (&png, &png_bytes)];
    files.extend(json.map(|j| (js.as_path(), j)));
    files.extend(var_bytes.as_deref().map(|v| (var.as_path(), v)));
    // An OUT.var.exr of an earlier render would sit beside the new image as if it were
    // its own (it carries no tag to tell): removed once the set is in place, before
    // another run's set may land (a render with --variance to the same output, whose
    // OUT.var.exr was left beside this render's image when it landed in between). Only an
    // untagged image with no PNG beside it, as variance images are written: a render,
    // montage or map the user named OUT.var (its EXR is OUT.var.exr) has OUT.var.png, and
    // a render its tag; one was deleted as a stale variance image.
    // Nor a file this command read: an environment map named OUT.var.exr (untagged, no
    // PNG) was deleted by the render that had just read it.
    let read = {
        let v = crate::paths::identity(&var);
        inputs.iter().any(|(_, p)| crate::paths::identity(p) == v)
    };
    let remove_stale = || {
        if variance.is_some() || !var.is_file() || foreign_var_exr(out) || read {
            return;
        }
        match std::fs::remove_file(&var) {
            Ok(()) => eprintln!(
                "note: removed {}, the variance image of an earlier render under this name",
                crate::paths::shown(&var)
            ),
            Err(e) => eprintln!(
                "warning: {} is the variance image of an earlier render and could not be \
                 removed ({e}): it does not belong to the new image",
                crate::paths::shown(&var)
            ),
        }
    };
    scatter_sim::output::write_atomic_set_then(&files, remove_stale)
        .map_err(|(path, e)| anyhow!("cannot write {}: {e}", path.display()))?;
    Ok(())
}

/// Renders of one scene with different seeds, averaged by spp: writes OUT.exr, OUT.png and
/// OUT.json.
fn merge_images(a: &Args) -> Result<()> {
    crate::render::check_out_stem(&a.out)?;
    // Ctrl-C asks to stop. Before the set is written (large renders take seconds to read)
    // nothing is; once writing, the set is finished whole (exit status 128 + the stop
    // signal either way, 130 for Ctrl-C). Without the handler the signal ended the process mid-write, leaving
    // hidden temporaries, or a new image beside the old report between two renames.
    let cancel = crate::interrupt::flag();
    let inputs: Vec<&std::path::Path> = a.inputs.iter().map(|p| p.as_path()).collect();
    let (img, tag) = render_gpu::image_io::merge_exrs(&inputs)?;
    if cancel.load(std::sync::atomic::Ordering::Relaxed) {
        bail!(
            "interrupted: nothing written to {}.{{exr,png,json}}",
            out_stem(&a.out).display()
        );
    }
    let reports = input_reports(&a.inputs);
    let exposure = match a.exposure {
        Some(e) => e,
        None => inputs_exposure(&a.inputs, &reports),
    };
    let (mut integrator, devices) = inputs_origin(&reports);
    let renders = inputs_renders(&a.inputs, &reports);
    let complete = renders_complete(&renders, &tag);
    // Every input has a report and every image its seeds, yet the reports' seeds or spp
    // are not the images': a report left from an earlier render of that name, or edited.
    // It is listed as it is (renders_complete says false), but its integrator is not
    // taken for the merge's, and the user is told.
    if !complete && !tag.some_unknown() && reports.iter().all(Option::is_some) {
        eprintln!(
            "warning: the inputs' reports do not match their images (their seeds or spp \
             differ from the EXR headers': a report left from another render, or edited); \
             the merged report lists them as they are, with renders_complete false and no \
             integrator"
        );
        integrator = None;
    }
    let report = serde_json::json!({
        // As the render report: which stcvae merged them.
        "version": env!("CARGO_PKG_VERSION"),
        "inputs": a.inputs.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "integrator": integrator,
        "devices": devices,
        "exposure": exposure,
        "spp": tag.spp,
        "scene_hash": format!("{:016x}", tag.scene_hash),
        // Null where an input was written before views were recorded.
        "view_hash": tag.view_hash.map(|v| format!("{v:016x}")),
        "seeds": tag.seeds,
        // As the render report's seed_text: readers that hold numbers as doubles (jq,
        // JavaScript) round seeds above 2^53, and two seeds read as one.
        "seeds_text": tag.seeds.iter().map(|s| s.to_string()).collect::<Vec<_>>(),
        // Whether inputs of unknown seed (older files, paired averages) are in it too.
        "unknown_seeds": tag.some_unknown(),
        "width": img.width,
        "height": img.height,
        "mean_rgb": crate::render::mean_rgb(&img),
        "renders_complete": complete,
        "renders": renders,
    });
    write_image_set(
        &a.out,
        &img,
        &tag,
        exposure,
        Some(&serde_json::to_vec_pretty(&report)?),
    )?;
    eprintln!(
        "merged {} ({} spp in all) -> {}.{{exr,png,json}}",
        progress::count(inputs.len() as u64, "render"),
        tag.spp,
        crate::paths::shown(&out_stem(&a.out))
    );
    // Asked to stop while writing: the set is whole, and the exit status says the stop
    // was asked for (128 + the stop signal, 130 for Ctrl-C), as an interrupted render's
    // does.
    if cancel.load(std::sync::atomic::Ordering::Relaxed) {
        bail!("interrupted while writing: the merged set was written whole");
    }
    Ok(())
}

/// The inputs' reports (IN.json beside each IN.exr), None where one is missing or not
/// JSON. They are trusted for the merged report only: the image and its spp come from the
/// EXRs' own headers. A report that is there but cannot be read is named in a warning:
/// silently, its render's entry in the merged report came out all nulls, as if it had none.
fn input_reports(inputs: &[PathBuf]) -> Vec<Option<serde_json::Value>> {
    inputs
        .iter()
        .map(|p| {
            let path = p.with_extension("json");
            // Not there at all: quietly none. A link to nothing, or one in a folder that
            // cannot be read, is there and unreadable: warned of below.
            if std::fs::symlink_metadata(&path)
                .is_err_and(|e| e.kind() == std::io::ErrorKind::NotFound)
            {
                return None;
            }
            let read = scatter_sim::output::read_input_to_string(&path)
                .map_err(|e| e.to_string())
                .and_then(|t| {
                    serde_json::from_str::<serde_json::Value>(&t).map_err(|e| e.to_string())
                })
                .and_then(|v| {
                    v.is_object()
                        .then_some(v)
                        .ok_or_else(|| "not a JSON object".to_string())
                });
            match read {
                Ok(v) => Some(v),
                Err(e) => {
                    eprintln!(
                        "warning: {}: the render's report could not be read ({e}); the merged \
                         report lists that render without its details",
                        path.display()
                    );
                    None
                }
            }
        })
        .collect()
}

/// What the inputs' reports say about how they were made: the integrator where every
/// report names the same one (null where one is missing; the scene hash, which includes
/// it, already refused a mix), and the devices they ran on, each once, in the inputs'
/// order (a merge's own report gives its devices).
fn inputs_origin(reports: &[Option<serde_json::Value>]) -> (Option<String>, Vec<String>) {
    let text = |v: &serde_json::Value, k: &str| v.get(k)?.as_str().map(str::to_owned);
    let kinds: Vec<Option<String>> = reports
        .iter()
        .map(|r| r.as_ref().and_then(|v| text(v, "integrator")))
        .collect();
    let integrator = match kinds.first() {
        Some(Some(k)) if kinds.iter().all(|x| x.as_ref() == Some(k)) => Some(k.clone()),
        _ => None,
    };
    let mut devices: Vec<String> = Vec::new();
    for v in reports.iter().flatten() {
        let found = text(v, "device").into_iter().chain(
            v.get("devices")
                .and_then(|d| d.as_array())
                .into_iter()
                .flatten()
                .filter_map(|d| d.as_str().map(str::to_owned)),
        );
        for d in found {
            if !devices.contains(&d) {
                devices.push(d);
            }
        }
    }
    (integrator, devices)
}

/// Each render in the merge as its report describes it (how many samples, which seed,
/// device and model, whether a time budget or a stop cut it short, how long it took),
/// nulls where its report is missing; a merged input contributes the renders its own
/// report lists, or, written before the list existed, one entry marked `merged`. The
/// merged report's totals alone lost which render was interrupted or ran where.
fn inputs_renders(
    inputs: &[PathBuf],
    reports: &[Option<serde_json::Value>],
) -> Vec<serde_json::Value> {
    const KEYS: [&str; 9] = [
        "spp",
        "seed_text",
        "device",
        "integrator",
        "model",
        "model_hash",
        "time_budget",
        "interrupted",
        "seconds",
    ];
    let mut out = Vec::new();
    for (p, r) in inputs.iter().zip(reports) {
        if let Some(inner) = r.as_ref().and_then(|v| v.get("renders")?.as_array()) {
            out.extend(inner.iter().cloned());
            continue;
        }
        let mut entry = serde_json::Map::new();
        entry.insert("file".into(), p.display().to_string().into());
        // A merge written before `renders` existed: one entry for its renders, with the
        // seeds and devices it recorded.
        let keys: &[&str] = if r.as_ref().is_some_and(|v| v.get("inputs").is_some()) {
            entry.insert("merged".into(), true.into());
            &["spp", "seeds_text", "devices", "integrator"]
        } else {
            &KEYS
        };
        for &k in keys {
            let v = r.as_ref().and_then(|v| v.get(k)).cloned();
            entry.insert(k.into(), v.unwrap_or(serde_json::Value::Null));
        }
        out.push(entry.into());
    }
    out
}

/// Whether the renders listed account for every sample of the merged image: their
/// reports' spp add up to the EXR headers' and their seeds are the headers' seeds. Not
/// where a report is missing, damaged or stale (a render redone with another seed after
/// its report was written).
fn renders_complete(renders: &[serde_json::Value], tag: &render_gpu::image_io::RenderTag) -> bool {
    let mut spp = Some(0u64);
    let mut seeds: Vec<String> = Vec::new();
    for r in renders {
        spp = spp
            .zip(r.get("spp").and_then(|v| v.as_u64()))
            .and_then(|(a, b)| a.checked_add(b));
        if let Some(s) = r.get("seed_text").and_then(|v| v.as_str()) {
            seeds.push(s.to_owned());
        }
        let merged = r.get("seeds_text").and_then(|v| v.as_array());
        seeds.extend(
            merged
                .into_iter()
                .flatten()
                .filter_map(|s| s.as_str().map(str::to_owned)),
        );
    }
    let mut want: Vec<String> = tag.seeds.iter().map(u64::to_string).collect();
    seeds.sort();
    want.sort();
    spp == Some(tag.spp) && seeds == want && !tag.some_unknown()
}

/// The preview exposure the renders' reports (a merge's own report records it too) agree
/// on; 1 where one has none or they differ (said so). One that is there but no exposure
/// (an edited report: −5, 0, a string) is named and counts as none; it was passed over
/// without a word.
fn inputs_exposure(inputs: &[PathBuf], reports: &[Option<serde_json::Value>]) -> f32 {
    let recorded = |(p, v): (&PathBuf, &Option<serde_json::Value>)| -> Option<f32> {
        let value = v.as_ref()?.get("exposure")?;
        let e = value.as_f64().map(|e| e as f32);
        let e = e.filter(|e| e.is_finite() && *e > 0.0);
        if e.is_none() {
            eprintln!(
                "note: {}: exposure = {value} is not a preview exposure (> 0 and finite as an \
                 f32): taken as none",
                p.with_extension("json").display()
            );
        }
        e
    };
    let found: Vec<Option<f32>> = inputs.iter().zip(reports).map(recorded).collect();
    match found.first() {
        Some(&Some(e)) if found.iter().all(|f| *f == Some(e)) => e,
        _ => {
            if found.iter().any(|f| f.is_some_and(|e| e != 1.0)) {
                eprintln!(
                    "note: the inputs' previews were not all at one recorded exposure: the \
                     merged PNG is at exposure 1 (--exposure sets it)"
                );
            }
            1.0
        }
    }
}

/// Reads a dataset to its end, which verifies its checksum.
fn read_through(path: &std::path::Path) -> Result<()> {
    let mut r = DatasetReader::open(path)?;
    while r.next_row()?.is_some() {}
    Ok(())
}

fn merge_binary(a: &Args) -> Result<()> {
    // Headers first, each file closed again: one reader is open at a time while the rows
    // are copied (1,100 shards ran out of file descriptors at the usual limit of 1,024,
    // with a 1 MiB buffer each).
    let headers = a
        .inputs
        .iter()
        .map(|p| DatasetReader::open(p).map(|r| r.header().clone()))
        .collect::<Result<Vec<_>, _>>()?;
    let first = headers[0].pieces.first().cloned();
    let one_run = first.is_some()
        && headers
            .iter()
            .flat_map(|h| &h.pieces)
            .all(|p| first.as_ref().is_some_and(|f| f.same_run(p)));
    let segments = segments_of(&headers, one_run);
    let correlated = check_overlaps(a, &segments)?;
    let pieces = coalesce(segments.iter().map(|s| s.piece.clone()));
    let header = Header::new(pieces);
    // Said after the rows, which may still be refused: a note above an error reads as
    // part of it.
    let note = coverage_note(&header, one_run);
    let cancel = crate::interrupt::flag();
    let pb = progress::bar(header.count, "rows");
    let mut sink = dataset::create_sink(&a.out, header.clone())?;
    copy_rows(a, &headers, &segments, sink.as_mut(), &pb, cancel)?;
    sink.finish()?;
    pb.finish_and_clear();
    for note in note
        .iter()
        .chain(&correlated)
        .chain(&simulators_note(&header))
    {
        eprintln!("{note}");
    }
    eprintln!(
        "merged {}, {} -> {}",
        progress::count(a.inputs.len() as u64, "file"),
        progress::count(header.count, "row"),
        crate::paths::shown(&a.out)
    );
    warn_if_empty(header.count, &a.out);
    Ok(())
}

/// A merge of inputs without rows (a header-only CSV, an empty shard) writes a valid
/// empty dataset, which `train` refuses only later: said now, as `generate` says of a
/// shard that holds no walk.
fn warn_if_empty(rows: u64, out: &Path) {
    if rows == 0 {
        eprintln!(
            "warning: the inputs hold no row: {} is an empty dataset, which no model can be \
             trained on",
            crate::paths::shown(out)
        );
    }
}

/// Each piece of each input, where its rows lie in the file; shards of one run go in
/// walk order, piece by piece: an input that is itself a merge of shards 0 and 2 puts
/// shard 1's rows between its two pieces, as the unsharded run has them.
fn segments_of(headers: &[Header], one_run: bool) -> Vec<Segment> {
    let mut segments: Vec<Segment> = Vec::new();
    for (input, h) in headers.iter().enumerate() {
        let mut offset = 0;
        for piece in &h.pieces {
            segments.push(Segment {
                input,
                offset,
                piece: piece.clone(),
            });
            offset += piece.count;
        }
    }
    if one_run {
        segments.sort_by_key(|s| s.piece.first_walk);
    }
    segments
}

/// Refuses duplicated walks (two pieces of one stream that overlap), and returns the
/// warning for pieces of one seed under two condition samplers, whose rows are correlated.
fn check_overlaps(a: &Args, segments: &[Segment]) -> Result<Option<String>> {
    // Pieces of one seed under two condition samplers draw walk i from the same random
    // numbers: rows of the same walk indices are correlated (said, not refused: training
    // on them is sound, only worth less than as many independent walks).
    let mut correlated: Option<String> = None;
    // Refuse duplicated walks: two pieces of one stream that overlap (of one run, or of two
    // runs of one seed and sampler but different sizes, whose walk i is the same walk).
    for (i, ps) in segments.iter().enumerate() {
        for qs in &segments[i + 1..] {
            let (p, q) = (&ps.piece, &qs.piece);
            // Pieces that share walk indices (an empty piece shares none).
            let overlap = p.count > 0
                && q.count > 0
                && p.first_walk < q.first_walk + q.count
                && q.first_walk < p.first_walk + p.count;
            if overlap && p.seed == q.seed && !p.same_stream(q) && correlated.is_none() {
                let (from, to) = (
                    p.first_walk.max(q.first_walk),
                    (p.first_walk + p.count).min(q.first_walk + q.count),
                );
                correlated = Some(format!(
                    "warning: walks {from}..{to} of seed {} appear under two condition \
                     samplers, drawn from the same random numbers: their rows are correlated \
                     (generate the runs with different --seed)",
                    p.seed
                ));
            }
            if overlap && p.same_stream(q) {
                // The headers are not yet checked against their files' checksums: a
                // corrupt one (a digit changed) read as overlapping shards.
                read_through(&a.inputs[ps.input])?;
                read_through(&a.inputs[qs.input])?;
                bail!(
                    "inputs overlap: walks {}..{} and {}..{} of seed {} appear twice{}",
                    p.first_walk,
                    p.first_walk + p.count,
                    q.first_walk,
                    q.first_walk + q.count,
                    p.seed,
                    if p.same_run(q) {
                        String::new()
                    } else {
                        format!(
                            " (runs of {} and {} walks with the same seed and conditions share \
                             their first walks)",
                            p.total_walks, q.total_walks
                        )
                    }
                );
            }
        }
    }
    Ok(correlated)
}

/// What the merged file lacks of its run (one run), or which runs it holds (several).
fn coverage_note(header: &Header, one_run: bool) -> Option<String> {
    if one_run {
        let covered: u64 = header.count;
        let total = header.pieces[0].total_walks;
        (covered != total).then(|| {
            // A shard missing from a cluster's merge (a job that failed) was one line of
            // "note" among the progress output: say which walks, as a warning.
            let gaps = missing_walks(&header.pieces, total);
            let named: Vec<String> = gaps
                .iter()
                .take(3)
                .map(|(a, b)| format!("{a}..{b}"))
                .collect();
            format!(
                "warning: the inputs hold {covered} of the run's {total} walks; missing: \
                 walks {}{} (merge the missing shards too to rebuild the run)",
                named.join(", "),
                if gaps.len() > 3 {
                    format!(" and {} more ranges", gaps.len() - 3)
                } else {
                    String::new()
                }
            )
        })
    } else {
        runs_note(&header.pieces)
    }
}

/// Copies every segment's rows into `sink`, reading each input to its end so that its
/// checksum is verified.
fn copy_rows(
    a: &Args,
    headers: &[Header],
    segments: &[Segment],
    sink: &mut dyn dataset::RowSink,
    pb: &indicatif::ProgressBar,
    cancel: &std::sync::atomic::AtomicBool,
) -> Result<()> {
    let stopped = || {
        // (The sink's temporary file is removed as it is dropped.)
        if cancel.load(std::sync::atomic::Ordering::Relaxed) {
            bail!("interrupted: nothing written to {}", a.out.display());
        }
        Ok(())
    };
    // Each input's checksum is verified by reading it to its end: as its last piece is
    // copied, or (a piece taken out of file order, from a merge of merges) afterwards.
    let mut verified = vec![false; headers.len()];
    let mut done_with = |(input, mut r): (usize, DatasetReader)| -> Result<()> {
        if r.rows_read() == headers[input].count {
            r.next_row()?;
            verified[input] = true;
        }
        Ok(())
    };
    let open = |input: usize| -> Result<DatasetReader> {
        let r = DatasetReader::open(&a.inputs[input])?;
        if *r.header() != headers[input] {
            bail!("{}: changed while being merged", a.inputs[input].display());
        }
        Ok(r)
    };
    let mut current: Option<(usize, DatasetReader)> = None;
    for s in segments {
        let reuse = matches!(&current, Some((i, r)) if *i == s.input && r.rows_read() == s.offset);
        if !reuse {
            if let Some(c) = current.take() {
                done_with(c)?;
            }
            let mut r = open(s.input)?;
            for _ in 0..s.offset {
                r.next_row()?;
                stopped()?;
            }
            current = Some((s.input, r));
        }
        let (_, r) = current.as_mut().expect("opened above");
        for _ in 0..s.piece.count {
            let Some(row) = r.next_row()? else {
                bail!(
                    "{}: ended before its header's row count",
                    r.path().display()
                );
            };
            sink.push(&row)?;
            pb.inc(1);
            stopped()?;
        }
    }
    if let Some(c) = current.take() {
        done_with(c)?;
    }
    for input in (0..headers.len()).filter(|&i| !verified[i]) {
        let mut r = open(input)?;
        while r.next_row()?.is_some() {
            stopped()?;
        }
    }
    Ok(())
}

/// Where the pieces were drawn by different simulators ([`dataset::simulator_fingerprint`],
/// recorded since format version 3), a warning naming them: shards of one run generated
/// by two builds (a cluster's nodes updated between jobs) hold walks from two
/// distributions, which merged as one run unsaid.
fn simulators_note(header: &Header) -> Option<String> {
    let (seen, unrecorded) = header.simulators();
    if seen.len() > 1 {
        Some(format!(
            "warning: the inputs were drawn by {} simulators ({}; this build's is {}): their \
             walks may differ in distribution, not only in their random numbers{}",
            seen.len(),
            seen.join(", "),
            dataset::simulator_fingerprint(),
            if unrecorded {
                "; some inputs (format 1 or 2) do not record theirs"
            } else {
                ""
            }
        ))
    } else {
        // Nothing shows that an older file's simulator differs: said as a note.
        (unrecorded && !seen.is_empty()).then(|| {
            format!(
                "note: some inputs (format 1 or 2) do not record their simulator; the others' \
                 is {}",
                seen[0]
            )
        })
    }
}

/// The walk ranges of a run of `total` walks that `pieces` (of that run, in walk order,
/// without overlaps) leave out.
fn missing_walks(pieces: &[Piece], total: u64) -> Vec<(u64, u64)> {
    let mut gaps = Vec::new();
    let mut next = 0;
    for p in pieces.iter().filter(|p| p.count > 0) {
        if p.first_walk > next {
            gaps.push((next, p.first_walk));
        }
        next = next.max(p.first_walk + p.count);
    }
    if next < total {
        gaps.push((next, total));
    }
    gaps
}

/// One piece of an input dataset: its rows start `offset` rows into the file.
struct Segment {
    input: usize,
    offset: u64,
    piece: Piece,
}

/// Where the pieces come from more than one run (`generate` with other seeds, sizes or
/// condition samplers), a note naming each run and how much of it the merge holds: a
/// merge of shards is usually meant to rebuild one run, so mixing runs should not pass
/// unsaid, though merging several runs on purpose is allowed.
fn runs_note(pieces: &[Piece]) -> Option<String> {
    let mut runs: Vec<(&Piece, u64)> = Vec::new();
    for p in pieces {
        match runs.iter_mut().find(|(r, _)| r.same_run(p)) {
            Some((_, count)) => *count += p.count,
            None => runs.push((p, p.count)),
        }
    }
    (runs.len() > 1).then(|| {
        // Runs of one seed and size differ in their condition sampler: named then, or the
        // note listed the same words twice.
        // At most 10 named: 76,000 runs made one line of megabytes.
        let each: Vec<String> = runs
            .iter()
            .take(10)
            .map(|(r, count)| {
                let twin = runs.iter().any(|(o, _)| {
                    !std::ptr::eq(*o, *r) && o.seed == r.seed && o.total_walks == r.total_walks
                });
                let sampler = if twin {
                    format!(
                        ", conditions {}",
                        serde_json::to_string(&r.sampler).unwrap_or_default()
                    )
                } else {
                    String::new()
                };
                format!(
                    "seed {} ({count} of its {} walks{sampler})",
                    r.seed, r.total_walks
                )
            })
            .collect();
        let more = runs.len() - each.len();
        format!(
            "note: the inputs come from {} different runs: {}{}",
            runs.len(),
            each.join(", "),
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            }
        )
    })
}

/// Joins adjacent pieces of one run that continue each other.
fn coalesce(pieces: impl Iterator<Item = Piece>) -> Vec<Piece> {
    let mut out: Vec<Piece> = Vec::new();
    for p in pieces {
        if let Some(last) = out.last_mut()
            && last.same_run(&p)
            && last.simulator == p.simulator
            && last.first_walk + last.count == p.first_walk
        {
            last.count += p.count;
            continue;
        }
        out.push(p);
    }
    out
}

/// Whether the file's last byte is a newline.
fn ends_with_newline(path: &Path) -> Result<bool> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let mut last = [0u8];
    f.seek(SeekFrom::End(-1))
        .and_then(|_| f.read_exact(&mut last))
        .with_context(|| format!("cannot read {}", path.display()))?;
    Ok(last[0] == b'\n')
}

fn merge_csv(a: &Args) -> Result<()> {
    if !dataset::is_csv(&a.out) {
        bail!(
            "--out {}: CSV inputs can only be merged into a .csv output",
            a.out.display()
        );
    }
    let cancel = crate::interrupt::flag();
    let mut out =
        AtomicFile::create(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut rows = 0u64;
    // Per input a digest of its rows: a shard copied under another name would count twice
    // (binary shards are told apart by their headers, CSV files only by their rows).
    let mut digests: Vec<(u64, u64)> = Vec::with_capacity(a.inputs.len());
    for (i, path) in a.inputs.iter().enumerate() {
        let mut digest = DefaultHasher::new();
        let mut own_rows = 0u64;
        scatter_sim::output::check_input(path)
            .with_context(|| format!("cannot open {}", path.display()))?;
        let f = File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
        let mut lines = BufReader::new(f).lines();
        let head = lines
            .next()
            .transpose()
            .with_context(|| format!("{}: line 1", path.display()))?
            .with_context(|| format!("{}: empty file", path.display()))?;
        // A spreadsheet's save starts with a byte-order mark; CRLF ends are read below.
        let head = head
            .strip_prefix('\u{feff}')
            .unwrap_or(&head)
            .trim_end_matches('\r');
        if head != dataset::COLUMNS.join(",") {
            bail!(
                "{}: not an stcvae walk CSV (unexpected header row)",
                path.display()
            );
        }
        if i == 0 {
            writeln!(out, "{head}").with_context(|| format!("cannot write {}", a.out.display()))?;
        }
        // The first blank line since the last row: stcvae writes none, so one followed by
        // more rows is a row emptied (an edit gone wrong), which was skipped silently.
        let mut blank: Option<usize> = None;
        for (n, line) in lines.enumerate() {
            // Line numbers count from 1, with the header as line 1.
            let line = line.with_context(|| format!("{}: line {}", path.display(), n + 2))?;
            // Blank lines at the end (an editor's trailing newlines) carry no row.
            if line.trim().is_empty() {
                blank.get_or_insert(n + 2);
                continue;
            }
            if let Some(at) = blank {
                bail!(
                    "{}: line {at}: a blank line among the rows (a row emptied?); stcvae \
                     writes none: remove it or restore the row",
                    path.display()
                );
            }
            // Checked as a binary row is: a truncated, edited or foreign row is refused.
            dataset::Row::parse_csv(&line)
                .map_err(|e| anyhow!("{}: line {}: {e}", path.display(), n + 2))?;
            writeln!(out, "{line}").with_context(|| format!("cannot write {}", a.out.display()))?;
            digest.write(line.trim_end().as_bytes());
            digest.write(b"\n");
            own_rows += 1;
            rows += 1;
            // (The temporary file is removed as `out` is dropped.)
            if cancel.load(std::sync::atomic::Ordering::Relaxed) {
                bail!("interrupted: nothing written to {}", a.out.display());
            }
        }
        // stcvae ends every row with a newline; a last row without one is a file cut short,
        // whose last number read shorter (-0.32728904 as -0.3272) and passed its range
        // check.
        // (Blank lines after the last row, as an editor leaves them, show it whole.)
        if own_rows > 0 && blank.is_none() && !ends_with_newline(path)? {
            bail!(
                "{}: the last row has no line end: the file was cut short (truncated?); \
                 nothing written to {}",
                path.display(),
                a.out.display()
            );
        }
        let d = (digest.finish(), own_rows);
        if let Some(j) = digests.iter().position(|e| *e == d && d.1 > 0) {
            bail!(
                "{} and {} hold the same rows: a shard given twice would count twice (nothing \
                 written to {})",
                a.inputs[j].display(),
                path.display(),
                a.out.display()
            );
        }
        digests.push(d);
    }
    out.commit()
        .with_context(|| format!("cannot write {}", a.out.display()))?;
    eprintln!(
        "merged {}, {} -> {}",
        progress::count(a.inputs.len() as u64, "file"),
        progress::count(rows, "row"),
        crate::paths::shown(&a.out)
    );
    warn_if_empty(rows, &a.out);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use render_gpu::image_io::RenderTag;
    use serde_json::json;

    /// The merge names an integrator only where every input's report names that one: a
    /// render whose report is missing may have been drawn by another.
    #[test]
    fn the_integrator_is_named_only_where_every_report_agrees() {
        let pt = json!({"integrator": "pt", "device": "cpu: X"});
        assert_eq!(
            inputs_origin(&[Some(pt.clone()), None]),
            (None, vec!["cpu: X".to_string()])
        );
        let st = json!({"integrator": "stcvae"});
        assert_eq!(inputs_origin(&[Some(pt.clone()), Some(st)]).0, None);
        assert_eq!(
            inputs_origin(&[Some(pt.clone()), Some(pt)]).0.as_deref(),
            Some("pt")
        );
    }

    /// A recorded exposure of 0 (an edited report) is no preview exposure: taken as none,
    /// the merged preview is at 1, not black at 0.
    #[test]
    fn a_recorded_exposure_of_zero_is_none() {
        let inputs = [PathBuf::from("a.exr"), PathBuf::from("b.exr")];
        let at = |e: f64| Some(json!({ "exposure": e }));
        assert_eq!(inputs_exposure(&inputs, &[at(0.0), at(0.0)]), 1.0);
        assert_eq!(inputs_exposure(&inputs, &[at(4.0), at(4.0)]), 4.0);
    }

    #[test]
    fn the_renders_list_is_complete_only_with_every_sample_and_seed() {
        let tag = RenderTag {
            spp: 5,
            scene_hash: 1,
            seeds: vec![1, 2, 3],
            partial: false,
            unknown_digests: Vec::new(),
            view_hash: None,
        };
        let render = |spp: u64, seed: &str| json!({"spp": spp, "seed_text": seed});
        let merged = json!({"merged": true, "spp": 3, "seeds_text": ["2", "3"]});
        assert!(renders_complete(&[render(2, "1"), merged.clone()], &tag));
        assert!(renders_complete(
            &[render(2, "1"), render(1, "2"), render(2, "3")],
            &tag
        ));
        // In any order of the inputs, and of seeds whose text sorts apart from their value
        // (9 and 10).
        assert!(renders_complete(
            &[render(2, "3"), render(1, "2"), render(2, "1")],
            &tag
        ));
        let nine_ten = RenderTag {
            seeds: vec![9, 10],
            spp: 3,
            ..tag.clone()
        };
        assert!(renders_complete(
            &[render(2, "9"), render(1, "10")],
            &nine_ten
        ));
        // A stale report (another seed, same spp), a missing one, spp that do not add up
        // or overflow, a render of unknown seed in the image.
        assert!(!renders_complete(&[render(2, "9"), merged.clone()], &tag));
        assert!(!renders_complete(&[json!({}), merged.clone()], &tag));
        assert!(!renders_complete(&[render(3, "1"), merged.clone()], &tag));
        assert!(!renders_complete(
            &[render(u64::MAX, "1"), merged.clone(), render(u64::MAX, "4")],
            &tag
        ));
        let partial = RenderTag {
            partial: true,
            ..tag.clone()
        };
        assert!(!renders_complete(&[render(2, "1"), merged], &partial));
    }
}
