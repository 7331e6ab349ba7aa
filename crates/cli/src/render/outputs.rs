//! The render's output names checked before it starts: a stem, not a folder; no input
//! overwritten; no other render's variance image replaced.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use render_gpu::scene::SceneFile;

use super::{Args, Prepared};

/// `--out` is a path stem (OUT.exr, OUT.png, OUT.json); checked before rendering so that a
/// long render is not lost to an unwritable name.
pub(crate) fn check_out_stem(out: &Path) -> Result<()> {
    crate::paths::check_not_stdout("--out", out)?;
    let text = out.as_os_str().to_string_lossy();
    if out.file_name().is_none()
        || text.ends_with('/')
        || text.ends_with(std::path::MAIN_SEPARATOR)
        || out.is_dir()
    {
        bail!(
            "--out {}: names a directory; give a path stem such as {}/render (writes render.exr, .png, .json)",
            out.display(),
            text.trim_end_matches(['/', std::path::MAIN_SEPARATOR])
        );
    }
    for dir in out.ancestors().skip(1) {
        if dir.as_os_str().is_empty() {
            break;
        }
        if dir.exists() {
            if !dir.is_dir() {
                bail!(
                    "--out {}: {} exists and is not a directory",
                    out.display(),
                    dir.display()
                );
            }
            break;
        }
    }
    // An output name taken by a folder (or a FIFO, a device), or a place without write
    // permission, would fail only after the render.
    for ext in ["exr", "png", "json"] {
        let f = crate::merge::image_out(out, ext);
        scatter_sim::output::check_output_path(&f)
            .map_err(|e| anyhow::anyhow!("--out {}: {e}", out.display()))?;
    }
    if let Some(render) = variance_image_owner(out) {
        bail!(
            "--out {}: {} is the variance image of the render {} (its JSON names it), which \
             this image would replace: choose another --out",
            out.display(),
            crate::merge::image_out(out, "exr").display(),
            render.display()
        );
    }
    Ok(())
}

/// The render whose variance image OUT.exr is, where OUT is named like one (`q.var`) and
/// render q's report says so: `render --out q.var` replaced q's variance image without a
/// word, while the other way round (`render --out q --variance` over a render q.var) was
/// refused.
fn variance_image_owner(out: &Path) -> Option<PathBuf> {
    let stem = crate::merge::out_stem(out);
    let render = stem.with_file_name(stem.file_name()?.to_str()?.strip_suffix(".var")?);
    let exr = crate::merge::image_out(out, "exr");
    if !exr.is_file() {
        return None;
    }
    // Read as inputs are: a FIFO named q.json would have held the command up.
    let text = scatter_sim::output::read_input_to_string(&crate::merge::image_out(&render, "json"))
        .ok()?;
    let json: serde_json::Value = serde_json::from_str(&text).ok()?;
    let named = json.get("variance_file")?.as_str()?;
    (Some(std::ffi::OsStr::new(named)) == exr.file_name()).then_some(render)
}

/// The files a render reads (and `--model`, even when PT leaves it unread): none may be
/// one of its outputs.
pub(super) fn render_inputs(a: &Args, p: &Prepared) -> Vec<(String, PathBuf)> {
    let mut v = scene_inputs(&a.scene, &p.file);
    v.extend(
        p.model_path
            .iter()
            .chain(&a.model)
            .map(|m| ("the model".to_string(), m.clone())),
    );
    v
}

/// The files a scene reads (the scene, its mesh and a glTF mesh's buffers, its environment
/// map), as `paths::check_not_input` takes them.
pub fn scene_inputs(scene: &Path, file: &SceneFile) -> Vec<(String, PathBuf)> {
    let dir = scene.parent().unwrap_or(Path::new("."));
    let field = |f: &str| format!("the scene's {f}");
    let mut v = vec![("--scene".to_string(), scene.to_path_buf())];
    if let Some(m) = &file.object.mesh {
        let mesh = dir.join(m);
        v.extend(
            render_gpu::mesh::gltf_buffer_files(&mesh)
                .into_iter()
                .map(|b| (field("object.mesh's buffer"), b)),
        );
        v.push((field("object.mesh"), mesh));
    }
    v.extend(
        file.environment
            .file
            .iter()
            .map(|f| (field("environment.file"), dir.join(f))),
    );
    v
}

/// The output files may be written: none is an input, and the variance image replaces no
/// other image.
pub(super) fn check_outputs(a: &Args, inputs: &[(String, PathBuf)]) -> Result<()> {
    let exts: &[&str] = if a.variance {
        &["exr", "png", "json", "var.exr"]
    } else {
        &["exr", "png", "json"]
    };
    for ext in exts {
        let f = crate::merge::image_out(&a.out, ext);
        crate::paths::check_not_input("--out", &f, inputs)?;
        if *ext == "var.exr" {
            scatter_sim::output::check_output_path(&f)
                .map_err(|e| anyhow::anyhow!("--out {}: {e}", a.out.display()))?;
            // A render named OUT.var had its image replaced by this one's variance.
            if crate::merge::foreign_var_exr(&a.out) {
                bail!(
                    "--out {}: {} is another image (a render or picture named {}), which \
                     the variance image would replace: choose another --out",
                    a.out.display(),
                    f.display(),
                    crate::merge::out_stem(&a.out).display().to_string() + ".var"
                );
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    /// An output named like a file the scene reads is refused, a glTF mesh's external
    /// buffer included: `render --out gb` wrote its gb.exr over the buffer of that name.
    #[test]
    fn outputs_naming_a_glb_buffer_or_another_scene_input_are_refused() {
        let d = tempfile::tempdir().unwrap();
        let gltf = r#"{"asset":{"version":"2.0"},"buffers":[{"uri":"g%20b.exr","byteLength":4}]}"#;
        std::fs::write(d.path().join("m.gltf"), gltf).unwrap();
        let scene = d.path().join("s.toml");
        let text = "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\nwidth = 8\nheight = 8\n\
                    [object]\nmesh = \"m.gltf\"\n[medium]\nsigma_t = [1.0, 1.0, 1.0]\n\
                    albedo = [0.5, 0.5, 0.5]\n[environment]\nfile = \"sky.exr\"\n";
        let file = render_gpu::scene::SceneFile::parse(&scene, text).unwrap();
        let inputs = super::scene_inputs(&scene, &file);
        for (name, what) in [
            ("g b.exr", "the scene's object.mesh's buffer"),
            ("m.gltf", "the scene's object.mesh"),
            ("sky.exr", "the scene's environment.file"),
            ("s.toml", "--scene"),
        ] {
            let e = crate::paths::check_not_input("--out", &d.path().join(name), &inputs)
                .unwrap_err()
                .to_string();
            assert!(e.contains(&format!("is also {what}")), "{name}: {e}");
        }
        crate::paths::check_not_input("--out", &d.path().join("r.exr"), &inputs).unwrap();
    }
}
