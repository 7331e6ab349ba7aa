//! The repository's shipped inputs (the default scene and model) found from any working
//! directory.
//!
//! The defaults (`configs/scenes/bunny.toml`, `models/default.stcvae`) are relative to the
//! repository root, which is where `cargo run` runs. A binary started elsewhere (a script in
//! another folder, `target/release/stcvae` called by its path, `cargo install --path
//! crates/cli`) falls back to the checkout it was built from while that still exists,
//! instead of failing. Outputs stay relative to the working directory.

use std::path::{Path, PathBuf};

/// `rel` in the working directory, else in the checkout this binary was built from, else
/// `rel` itself (the caller's "not found" names it).
pub fn locate(rel: &str) -> PathBuf {
    let here = Path::new(rel);
    if here.exists() {
        return here.to_path_buf();
    }
    let there = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .join(rel);
    match there.canonicalize() {
        Ok(p) => p,
        Err(_) => here.to_path_buf(),
    }
}

/// clap's parser for a path flag whose default is `default`, a shipped file (`what`: the
/// kind of file, for the empty path's refusal): that very string, given or defaulted, is
/// located as above, any other path taken as given. (`--model models/default.stcvae`,
/// typed, failed from another folder while `--scene configs/scenes/bunny.toml` was found.)
fn shipped_arg(
    default: &'static str,
    what: &'static str,
) -> impl Fn(&str) -> Result<PathBuf, String> + Clone {
    move |s: &str| {
        // As clap's own path parser refuses it: read, "" failed as ": cannot read scene
        // file".
        if s.is_empty() {
            return Err(format!("an empty path names no {what}"));
        }
        Ok(if s == default {
            locate(s)
        } else {
            PathBuf::from(s)
        })
    }
}

/// clap's parser for a `--scene` whose default is `default` ([`shipped_arg`]).
pub fn scene_arg(default: &'static str) -> impl Fn(&str) -> Result<PathBuf, String> + Clone {
    shipped_arg(default, "scene file")
}

/// clap's parser for `--model` and `train --base` ([`shipped_arg`]).
pub fn model_arg(s: &str) -> Result<PathBuf, String> {
    shipped_arg(crate::model_cmds::DEFAULT_MODEL, "model file")(s)
}
