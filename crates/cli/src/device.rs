//! `--device auto|gpu|cpu`: where a render runs, chosen once and said once.

use std::cell::Cell;
use std::sync::atomic::AtomicBool;

use anyhow::Result;
use render_gpu::error::RenderError;
use render_gpu::gpu::{AdapterChoice, GpuContext, render_gpu};
use render_gpu::integrator::IntegratorSettings;
use render_gpu::render::{RenderOptions, RenderOutput, render};
use render_gpu::setup::SceneData;

/// The CPU's model name where the OS reports one (Linux): CPU timings differ by 2× and
/// more between machines of one core count, and PT and ST-CVAE do not scale alike, so
/// reports, benches and the PT cache name it.
/// A scene with more lights than the GPU kernels take, refused before a bench prints its
/// banner, naming the scene (the render's own refusal came after the table's head,
/// without the file); `then` says what follows.
pub fn check_gpu_lights(scene: &std::path::Path, lights: usize, then: &str) -> Result<()> {
    let most = render_gpu::gpu::scene_buffers::MAX_GPU_LIGHTS;
    if lights > most {
        anyhow::bail!(
            "{}: {lights} lights; the GPU kernels take at most {most}{then}",
            scene.display()
        );
    }
    Ok(())
}

/// A note for a software adapter run with `LP_NATIVE_VECTOR_WIDTH` and Mesa's shader cache
/// on: the cache does not key on the width, so a warm cache serves kernels compiled at
/// another width while the adapter's name gives the new one. Four sessions' width
/// comparisons measured one width that way (docs/BENCHMARKS.md, sixty-second session).
pub fn vector_width_note(software: bool) -> Option<String> {
    let width = std::env::var("LP_NATIVE_VECTOR_WIDTH").ok();
    let cache_off = std::env::var("MESA_SHADER_CACHE_DISABLE").ok();
    width_note(software, width.as_deref(), cache_off.as_deref())
}

fn width_note(software: bool, width: Option<&str>, cache_off: Option<&str>) -> Option<String> {
    let off = cache_off.is_some_and(|v| matches!(v.trim(), "true" | "1" | "yes"));
    (software && width.is_some() && !off).then(|| {
        format!(
            "note: LP_NATIVE_VECTOR_WIDTH={} is set, but Mesa's shader cache does not key on \
             it: a kernel compiled before at another width may run instead (set \
             MESA_SHADER_CACHE_DISABLE=true, or clear ~/.cache/mesa_shader_cache*)",
            width.unwrap_or_default()
        )
    })
}

pub fn cpu_model() -> Option<String> {
    let info = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("model name"))?;
    let name = line
        .split_once(':')?
        .1
        .split_whitespace()
        .collect::<Vec<_>>();
    (!name.is_empty()).then(|| name.join(" "))
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DeviceArg {
    /// A hardware GPU if there is one, else the CPU integrators (a software adapter such
    /// as lavapipe is not used: on 2 cores it was slower than the CPU path; see
    /// docs/BENCHMARKS.md).
    Auto,
    /// The wgpu renderer on the best adapter, software adapters included; fails if none.
    Gpu,
    /// The CPU integrators (rayon threads).
    Cpu,
}

/// Where renders run. A GPU chosen by `auto` gives way to the CPU, for good, when a scene is
/// beyond it ([`RenderError::GpuLimit`], [`RenderError::SceneBeyondGpu`]); one chosen with
/// `--device gpu` reports that as the error.
pub struct Engine {
    gpu: Option<Box<GpuContext>>,
    auto: bool,
    fell_back: Cell<bool>,
}

impl Engine {
    /// Opens the device and prints one line saying which it is.
    pub fn open(arg: DeviceArg) -> Result<Self> {
        let gpu = match arg {
            DeviceArg::Cpu => None,
            DeviceArg::Gpu => Some(Box::new(GpuContext::new(AdapterChoice::Any)?)),
            DeviceArg::Auto => match GpuContext::new(AdapterChoice::Hardware) {
                Ok(c) => Some(Box::new(c)),
                Err(RenderError::NoAdapter(why)) => {
                    eprintln!("{why}: rendering on the CPU ({})", cpu_threads());
                    None
                }
                Err(e) => {
                    eprintln!(
                        "the GPU could not be used ({e}): rendering on the CPU ({})",
                        cpu_threads()
                    );
                    None
                }
            },
        };
        if let Some(c) = &gpu {
            eprintln!("GPU: {}", c.adapter);
            for why in &c.passed_over {
                eprintln!("  (passed over: {why})");
            }
            if let Some(note) = vector_width_note(c.adapter.software) {
                eprintln!("{note}");
            }
        }
        Ok(Self {
            gpu,
            auto: arg == DeviceArg::Auto,
            fell_back: Cell::new(false),
        })
    }

    /// No fall-back to the CPU after the device is chosen: a measurement (`bench`,
    /// `experiment`) must not change device part way, under a report that names the first.
    pub fn without_fallback(mut self) -> Self {
        self.auto = false;
        self
    }

    fn active_gpu(&self) -> Option<&GpuContext> {
        self.gpu.as_deref().filter(|_| !self.fell_back.get())
    }

    /// Whether renders now run on the GPU.
    pub fn is_gpu(&self) -> bool {
        self.active_gpu().is_some()
    }

    /// Whether renders run on a hardware GPU (not the CPU integrators, not a software
    /// adapter).
    pub fn is_hardware_gpu(&self) -> bool {
        self.active_gpu().is_some_and(|c| !c.adapter.software)
    }

    /// Where renders run, for reports and JSON: the CPU's model for the CPU integrators
    /// and for a software adapter (whose speed is that CPU's).
    pub fn describe(&self) -> String {
        let model = cpu_model();
        match (self.active_gpu(), model) {
            (None, Some(m)) => format!("cpu ({}, {m})", cpu_threads()),
            (None, None) => format!("cpu ({})", cpu_threads()),
            (Some(c), Some(m)) if c.adapter.software => format!("gpu: {} on {m}", c.adapter),
            (Some(c), _) => format!("gpu: {}", c.adapter),
        }
    }

    pub fn render(
        &self,
        scene: &SceneData,
        set: &IntegratorSettings,
        opts: &RenderOptions,
        progress: &(dyn Fn(u64, u64) + Sync),
        cancel: &AtomicBool,
    ) -> Result<RenderOutput> {
        let Some(c) = self.active_gpu() else {
            return Ok(render(scene, set, opts, progress, cancel));
        };
        match render_gpu(c, scene, set, opts, progress, cancel) {
            Err(RenderError::GpuLimit(why) | RenderError::SceneBeyondGpu(why)) if self.auto => {
                eprintln!("{why}: rendering on the CPU ({}) instead", cpu_threads());
                self.fell_back.set(true);
                Ok(render(scene, set, opts, progress, cancel))
            }
            r => Ok(r?),
        }
    }

    /// Untimed work before a timed render, on a hardware GPU only: one idle through the
    /// CPU's preparation of a scene runs its first timed render slower (`bench devices`
    /// measured ~30 % on an H100). A software adapter is the CPU, which that preparation
    /// keeps busy anyway, so a warm-up would not help it; the CPU needs none.
    pub fn warm_up(
        &self,
        scene: &SceneData,
        set: &IntegratorSettings,
        spp: u32,
        seed: u64,
        cancel: &AtomicBool,
    ) -> Result<()> {
        if self.is_hardware_gpu() {
            let opts = RenderOptions {
                spp,
                seed,
                time_budget: Some(crate::bench_devices::GPU_WARM_UP_SECONDS),
                variance: false,
            };
            self.render(scene, set, &opts, &|_, _| {}, cancel)?;
        }
        Ok(())
    }
}

/// "N threads" of the CPU path ("1 thread" under `RAYON_NUM_THREADS=1`).
fn cpu_threads() -> String {
    crate::progress::count(rayon::current_num_threads() as u64, "thread")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_vector_width_note_shows_only_where_the_cache_could_mislead() {
        assert!(width_note(true, Some("128"), None).is_some_and(|n| n.contains("=128")));
        assert!(width_note(true, Some("128"), Some("false")).is_some());
        assert!(width_note(true, Some("128"), Some("true")).is_none());
        assert!(width_note(true, Some("512"), Some("1")).is_none());
        assert!(width_note(true, None, None).is_none());
        assert!(width_note(false, Some("128"), None).is_none());
    }
}
