//! `--device auto|gpu|cpu`: where a render runs, chosen once and said once.

use std::sync::atomic::AtomicBool;

use anyhow::Result;
use render_gpu::error::RenderError;
use render_gpu::gpu::{AdapterChoice, GpuContext, render_gpu};
use render_gpu::integrator::IntegratorSettings;
use render_gpu::render::{RenderOptions, RenderOutput, render};
use render_gpu::setup::SceneData;

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

pub enum Engine {
    Cpu,
    Gpu(Box<GpuContext>),
}

impl Engine {
    /// Opens the device and prints one line saying which it is.
    pub fn open(arg: DeviceArg) -> Result<Self> {
        let e = match arg {
            DeviceArg::Cpu => Engine::Cpu,
            DeviceArg::Gpu => Engine::Gpu(Box::new(GpuContext::new(AdapterChoice::Any)?)),
            DeviceArg::Auto => match GpuContext::new(AdapterChoice::Hardware) {
                Ok(c) => Engine::Gpu(Box::new(c)),
                Err(RenderError::NoAdapter(_)) => {
                    eprintln!(
                        "no hardware GPU adapter: rendering on the CPU ({} threads); \
                         --device gpu accepts a software adapter",
                        rayon::current_num_threads()
                    );
                    Engine::Cpu
                }
                Err(e) => {
                    eprintln!(
                        "the GPU could not be used ({e}): rendering on the CPU ({} threads)",
                        rayon::current_num_threads()
                    );
                    Engine::Cpu
                }
            },
        };
        if let Engine::Gpu(c) = &e {
            eprintln!("GPU: {}", c.adapter);
        }
        Ok(e)
    }

    /// A short name for reports: "cpu" or the adapter.
    pub fn describe(&self) -> String {
        match self {
            Engine::Cpu => format!("cpu ({} threads)", rayon::current_num_threads()),
            Engine::Gpu(c) => format!("gpu: {}", c.adapter),
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
        Ok(match self {
            Engine::Cpu => render(scene, set, opts, progress, cancel),
            Engine::Gpu(c) => render_gpu(c, scene, set, opts, progress, cancel)?,
        })
    }
}
