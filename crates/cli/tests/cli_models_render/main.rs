//! End-to-end checks of `sample`, `eval`, `render`, image `merge` and the benches through
//! the binary, with the shipped model and scenes (run from the repository root). The
//! helpers every module uses are here.

mod benches;
#[path = "../common/mod.rs"]
mod common;
mod devices;
mod inputs;
mod merges;
mod models;
mod stops;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The shipped sphere scene at `side`² pixels.
fn sphere_scene_text(side: u32) -> String {
    let text = std::fs::read_to_string(root().join("configs/scenes/sphere.toml"))
        .unwrap()
        .replace("width = 128", &format!("width = {side}"))
        .replace("height = 128", &format!("height = {side}"));
    assert!(
        text.contains(&format!("width = {side}")),
        "the sphere scene's size changed"
    );
    text
}

/// The shipped sphere scene at `side`² pixels, written to `dir`/s.toml.
fn sphere_scene_file(dir: &Path, side: u32) -> PathBuf {
    let scene = dir.join("s.toml");
    std::fs::write(&scene, sphere_scene_text(side)).unwrap();
    scene
}

fn stcvae(args: &[&str]) -> Output {
    common::stcvae(args, &root())
}

/// `stcvae render` of `scene` with `integrator`, `spp` and `seed` into `out`, plus `extra`.
fn render_scene(
    scene: &Path,
    integrator: &str,
    spp: &str,
    seed: &str,
    out: &Path,
    extra: &[&str],
) -> Output {
    let mut args = vec![
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--integrator",
        integrator,
        "--spp",
        spp,
        "--seed",
        seed,
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    stcvae(&args)
}

/// `stcvae merge A.exr B.exr --out M` for render stems A, B and M.
fn merge_renders(a: &Path, b: &Path, m: &Path) -> Output {
    stcvae(&[
        "merge",
        a.with_extension("exr").to_str().unwrap(),
        b.with_extension("exr").to_str().unwrap(),
        "--out",
        m.to_str().unwrap(),
    ])
}

/// `stcvae ARGS` with wgpu narrowed to Vulkan (lavapipe in CI), which must succeed; None,
/// with the reason printed, only where no Vulkan adapter exists and not under CI.
fn on_vulkan(args: &[&str], test: &str) -> Option<Output> {
    let out = on_vulkan_any(args, &[], test)?;
    ok(&out);
    Some(out)
}

/// [`on_vulkan`] with `envs` set, without the check that it succeeds.
fn on_vulkan_any(args: &[&str], envs: &[(&str, &str)], test: &str) -> Option<Output> {
    let out = Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args(args)
        .envs(envs.iter().copied())
        .env("WGPU_BACKEND", "vulkan")
        .current_dir(root())
        .output()
        .expect("run stcvae");
    (!common::skipped_without_vulkan(&out, test)).then_some(out)
}

fn ok(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "stcvae failed: {err}");
    err
}

fn fails(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "stcvae should have failed");
    assert!(
        !err.contains("panicked"),
        "a panic instead of an error: {err}"
    );
    err
}

/// `stcvae render` of the sphere scene with PT at 2 spp on `device`, writing `out`.{exr,png,json}.
fn sphere_pt_render(device: &str, out: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_stcvae"));
    c.args([
        "render",
        "--scene",
        "configs/scenes/sphere.toml",
        "--integrator",
        "pt",
        "--spp",
        "2",
        "--device",
        device,
        "--out",
    ])
    .arg(out)
    .current_dir(root());
    c
}
