//! The wgpu device: one adapter chosen on purpose, its own limits requested, and a clear
//! error when there is none.

use std::fmt;

use crate::error::RenderError;

/// What a caller asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdapterChoice {
    /// Only hardware adapters (integrated, discrete or virtual GPUs).
    Hardware,
    /// Any adapter, software rasterisers such as Mesa's lavapipe included; hardware first.
    Any,
}

/// Name, backend and type of the adapter in use, as reported once per run.
#[derive(Clone, Debug, serde::Serialize)]
pub struct AdapterSummary {
    pub name: String,
    pub backend: String,
    pub device_type: String,
    pub driver: String,
    /// True for CPU-emulated adapters (lavapipe, SwiftShader, WARP).
    pub software: bool,
}

impl fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} ({}, {}{})",
            self.name,
            self.backend,
            self.device_type,
            if self.driver.is_empty() {
                String::new()
            } else {
                format!(", {}", self.driver)
            }
        )
    }
}

pub struct GpuContext {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub adapter: AdapterSummary,
    pub limits: wgpu::Limits,
}

fn summary(info: &wgpu::AdapterInfo) -> AdapterSummary {
    AdapterSummary {
        name: info.name.clone(),
        backend: format!("{:?}", info.backend),
        device_type: format!("{:?}", info.device_type),
        driver: format!("{} {}", info.driver, info.driver_info)
            .trim()
            .to_string(),
        software: info.device_type == wgpu::DeviceType::Cpu,
    }
}

fn rank(t: wgpu::DeviceType) -> u32 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

impl GpuContext {
    /// Opens the best adapter of `choice` on the native backends (Vulkan, Metal, DX12;
    /// `WGPU_BACKEND` narrows them). GL is not compiled in, so wgpu can never fall back
    /// to it silently.
    pub fn new(choice: AdapterChoice) -> Result<Self, RenderError> {
        Self::with_backends(choice, None)
    }

    /// As [`GpuContext::new`] with the backends given explicitly (tests pass Vulkan).
    pub fn with_backends(
        choice: AdapterChoice,
        backends: Option<wgpu::Backends>,
    ) -> Result<Self, RenderError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        desc.backends = backends
            .unwrap_or_else(|| wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY))
            & wgpu::Backends::PRIMARY;
        let instance = wgpu::Instance::new(desc);
        let mut adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
        adapters.retain(|a| {
            choice == AdapterChoice::Any || a.get_info().device_type != wgpu::DeviceType::Cpu
        });
        adapters.sort_by_key(|a| rank(a.get_info().device_type));
        let Some(adapter) = adapters.into_iter().next() else {
            // WGPU_BACKEND narrows the search (or, set to gl or to a name wgpu does not
            // know, leaves no native backend at all): say so, or the hint to install
            // lavapipe misleads on a machine that has it.
            if backends.is_none()
                && let Some(v) = std::env::var_os("WGPU_BACKEND")
            {
                return Err(RenderError::NoAdapter(format!(
                    "no wgpu adapter found with WGPU_BACKEND={} (this build uses vulkan, \
                     metal or dx12; gl is not compiled in); unset it or name one of those",
                    v.to_string_lossy()
                )));
            }
            return Err(RenderError::NoAdapter(match choice {
                AdapterChoice::Hardware => "no GPU adapter found (Vulkan, Metal or DX12); \
                    use --device cpu, or --device gpu to accept a software adapter such as \
                    Mesa's lavapipe (apt-get install mesa-vulkan-drivers)"
                    .into(),
                AdapterChoice::Any => "no wgpu adapter found (Vulkan, Metal or DX12); on \
                    Linux without a GPU driver install Mesa's lavapipe \
                    (apt-get install mesa-vulkan-drivers), or use --device cpu"
                    .into(),
            }));
        };
        let info = adapter.get_info();
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("stcvae"),
            required_features: wgpu::Features::empty(),
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| RenderError::Gpu(format!("cannot open {}: {e}", info.name)))?;
        Ok(Self {
            device,
            queue,
            adapter: summary(&info),
            limits,
        })
    }
}
