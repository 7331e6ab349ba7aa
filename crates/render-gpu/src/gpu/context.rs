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

impl AdapterChoice {
    fn admits(self, info: &wgpu::AdapterInfo) -> bool {
        self == AdapterChoice::Any || info.device_type != wgpu::DeviceType::Cpu
    }
}

/// `WGPU_BACKEND`, None when it is unset or blank (wgpu reads an empty value as no
/// backend at all, which left no adapter to find).
fn backend_var() -> Option<std::ffi::OsString> {
    std::env::var_os("WGPU_BACKEND").filter(|v| !v.to_string_lossy().trim().is_empty())
}

/// The backends `WGPU_BACKEND` names; None when [`backend_var`] is.
fn backends_from_env() -> Option<wgpu::Backends> {
    backend_var().and_then(|_| wgpu::Backends::from_env())
}

/// The adapters wgpu finds on `backends`; the instance's other settings come from the
/// environment.
fn adapters_on(backends: wgpu::Backends) -> Vec<wgpu::Adapter> {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
    desc.backends = backends;
    // wgpu guards every indirect dispatch with a dispatch of its own that zeroes arguments
    // beyond the adapter's limit: the staged render's three a turn would become six, each
    // a pause on a hardware GPU. Its arguments come from `dispatch_args`
    // (shaders/staged.wgsl), which keeps each within 65,535 (WebGPU's minimum limit), so
    // the guard is off unless WGPU_VALIDATION_INDIRECT_CALL is set (wgpu reads "0" as off
    // and any other value as on).
    if std::env::var_os("WGPU_VALIDATION_INDIRECT_CALL").is_none() {
        desc.flags
            .remove(wgpu::InstanceFlags::VALIDATION_INDIRECT_CALL);
    }
    pollster::block_on(wgpu::Instance::new(desc).enumerate_adapters(backends))
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
    /// The optional features opened with the device: subgroup operations where the adapter
    /// offers them (only the lane profile, `STCVAE_GPU_PROFILE`, uses them).
    pub features: wgpu::Features,
    /// The largest subgroup (SIMD group) the adapter may run: 8 on lavapipe, 32 on NVIDIA.
    pub subgroup_max_size: u32,
    /// Why adapters ranked above this one could not be opened, one line each (usually
    /// none); the caller reports them with the adapter.
    pub passed_over: Vec<String>,
    /// The first error wgpu reported outside an error scope since the last wait
    /// ([`GpuContext::poll`]), on one line: wgpu's default handler panics.
    uncaptured: std::sync::Arc<std::sync::Mutex<Option<String>>>,
    /// The layouts and pipelines made for earlier renders on this device.
    pub kernel_cache: super::kernel_cache::KernelCache,
}

/// wgpu's error text ("Validation Error\n\nCaused by:\n  …") on one line.
pub fn one_line(text: &str) -> String {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(" ")
}

impl GpuContext {
    /// Waits as `poll_type` says, then reports an error wgpu met meanwhile outside an error
    /// scope. A lost device (a driver reset, a watchdog) makes wgpu's poll panic instead of
    /// returning an error: that panic is caught and reported as an error too.
    pub fn poll(&self, poll_type: wgpu::PollType) -> Result<(), RenderError> {
        let polled = scatter_sim::quiet::quietly(|| self.device.poll(poll_type));
        let uncaptured = self
            .uncaptured
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take();
        if let Some(e) = uncaptured {
            return Err(RenderError::Gpu(format!(
                "{} reported an error: {e}; use --device cpu",
                self.adapter.name
            )));
        }
        match polled {
            Ok(Ok(_)) => Ok(()),
            Ok(Err(e)) => Err(RenderError::Gpu(format!(
                "the GPU did not finish: {}",
                one_line(&e.to_string())
            ))),
            Err(_) => Err(RenderError::Gpu(format!(
                "{} was lost while rendering (a driver reset or watchdog); use --device cpu",
                self.adapter.name
            ))),
        }
    }
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

/// Why no adapter was found, in words that name the fix. The messages read as a clause, so
/// that `--device auto` can append "rendering on the CPU".
///
/// `elsewhere`: adapters that the backends `WGPU_BACKEND` leaves out would have offered.
fn no_adapter(
    choice: AdapterChoice,
    backends: Option<wgpu::Backends>,
    software: &[String],
    elsewhere: &[String],
) -> String {
    // WGPU_BACKEND set to gl or to a name wgpu does not know leaves no native backend to
    // search, and one set to a backend this machine lacks (dx12 on Linux) hides the
    // adapters it has: that is the fault to name, or the hint to install lavapipe misleads
    // on a machine that has it. A value whose backend just lacks a driver is not at fault.
    if backends.is_none()
        && let Some(v) = backend_var()
    {
        let v = v.to_string_lossy();
        if backends_from_env().is_none_or(|b| (b & wgpu::Backends::PRIMARY).is_empty()) {
            return format!(
                "no wgpu adapter found with WGPU_BACKEND={v} (this build uses vulkan, metal \
                 or dx12; gl is not compiled in); unset it or name one of those"
            );
        }
        if let Some(name) = elsewhere.first() {
            return format!(
                "no wgpu adapter found with WGPU_BACKEND={v}, while {name} is there on \
                 another backend; unset it or name that backend"
            );
        }
    }
    match (choice, software.first()) {
        (AdapterChoice::Hardware, Some(name)) => format!(
            "no hardware GPU adapter (--device gpu would use the software adapter {name}, \
             slower than the CPU path)"
        ),
        (AdapterChoice::Hardware, None) => "no GPU adapter (Vulkan, Metal or DX12) found".into(),
        (AdapterChoice::Any, _) => "no wgpu adapter found (Vulkan, Metal or DX12): on Linux \
            without a GPU driver install Mesa's lavapipe (apt-get install \
            mesa-vulkan-drivers), or use --device cpu"
            .into(),
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
        let primary = wgpu::Backends::PRIMARY;
        let searched = backends.unwrap_or_else(|| backends_from_env().unwrap_or(primary)) & primary;
        let mut adapters = adapters_on(searched);
        let software: Vec<String> = adapters
            .iter()
            .map(|a| a.get_info())
            .filter(|i| i.device_type == wgpu::DeviceType::Cpu)
            .map(|i| i.name)
            .collect();
        adapters.retain(|a| choice.admits(&a.get_info()));
        adapters.sort_by_key(|a| rank(a.get_info().device_type));
        if adapters.is_empty() {
            // Only on this error path: what the backends WGPU_BACKEND left out would offer.
            let elsewhere: Vec<String> = if backends.is_none() && searched != primary {
                adapters_on(primary)
                    .iter()
                    .map(|a| a.get_info())
                    .filter(|i| choice.admits(i))
                    .map(|i| i.name)
                    .collect()
            } else {
                Vec::new()
            };
            return Err(RenderError::NoAdapter(no_adapter(
                choice, backends, &software, &elsewhere,
            )));
        }
        // An adapter that is listed may still fail to open (a driver that lists a GPU it
        // cannot start, out of memory): the next one in rank is tried, and the failures are
        // kept to be reported beside the one that opened.
        let opened = open_first(adapters, |adapter| {
            let limits = adapter.limits();
            let features = adapter.features() & wgpu::Features::SUBGROUP;
            pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
                label: Some("stcvae"),
                required_features: features,
                required_limits: limits.clone(),
                ..Default::default()
            }))
            .map(|dq| (dq, limits, features))
            .map_err(|e| {
                format!(
                    "cannot open {}: {}",
                    adapter.get_info().name,
                    one_line(&e.to_string())
                )
            })
        });
        let (adapter, ((device, queue), limits, features), passed_over) =
            opened.map_err(|failures| RenderError::Gpu(failures.join("; ")))?;
        let info = adapter.get_info();
        let uncaptured = std::sync::Arc::new(std::sync::Mutex::new(None::<String>));
        let sink = uncaptured.clone();
        device.on_uncaptured_error(std::sync::Arc::new(move |e: wgpu::Error| {
            let mut first = sink.lock().unwrap_or_else(|p| p.into_inner());
            if first.is_none() {
                *first = Some(one_line(&e.to_string()));
            }
        }));
        Ok(Self {
            device,
            queue,
            adapter: summary(&info),
            limits,
            features,
            subgroup_max_size: info.subgroup_max_size,
            passed_over,
            uncaptured,
            kernel_cache: Default::default(),
        })
    }
}

/// The first of `candidates` that `open` opens, with the reasons the ones before it
/// failed; every reason, in order, when none opens.
fn open_first<A, T>(
    candidates: Vec<A>,
    mut open: impl FnMut(&A) -> Result<T, String>,
) -> Result<(A, T, Vec<String>), Vec<String>> {
    let mut failures = Vec::new();
    for candidate in candidates {
        match open(&candidate) {
            Ok(t) => return Ok((candidate, t, failures)),
            Err(why) => failures.push(why),
        }
    }
    Err(failures)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The device opens with its adapter's own limits, not wgpu's defaults: the staged
    /// render's kernels bind nine storage buffers, one more than the default allows, and
    /// large images need the adapter's largest binding. Skipped, saying so, only where no
    /// Vulkan adapter exists outside CI (as the GPU tests).
    #[test]
    fn the_device_has_its_adapters_own_limits() {
        let vulkan = wgpu::Backends::VULKAN;
        let ctx = match GpuContext::with_backends(AdapterChoice::Any, Some(vulkan)) {
            Ok(c) => c,
            Err(RenderError::NoAdapter(e)) => {
                assert!(std::env::var_os("CI").is_none(), "CI must have Vulkan: {e}");
                // Past libtest's capture, which shows a passing test's output only with
                // --nocapture.
                use std::io::Write;
                let _ = writeln!(
                    std::io::stderr(),
                    "skipping the_device_has_its_adapters_own_limits: {e}"
                );
                return;
            }
            Err(e) => panic!("{e}"),
        };
        let adapter = adapters_on(vulkan)
            .into_iter()
            .find(|a| a.get_info().name == ctx.adapter.name)
            .expect("the adapter listed again");
        assert_eq!(ctx.device.limits(), adapter.limits());
        assert_eq!(ctx.limits, adapter.limits());
        assert_ne!(
            adapter.limits(),
            wgpu::Limits::default(),
            "a test that can fail"
        );
    }

    /// The first adapter that opens is taken, after the failures of those ranked above
    /// it, which are kept in order; when none opens, every failure is returned.
    #[test]
    fn the_next_adapter_is_tried_when_one_fails_to_open() {
        let open = |name: &&str| match *name {
            "good" | "also good" => Ok(name.len()),
            bad => Err(format!("cannot open {bad}")),
        };
        let (name, len, before) =
            open_first(vec!["broken", "lost", "good", "also good"], open).expect("one opens");
        assert_eq!((name, len), ("good", 4));
        assert_eq!(before, ["cannot open broken", "cannot open lost"]);
        assert_eq!(
            open_first(vec!["broken", "lost"], open).err(),
            Some(vec!["cannot open broken".into(), "cannot open lost".into()])
        );
        let (_, _, before) = open_first(vec!["good", "broken"], open).expect("first opens");
        assert!(before.is_empty());
    }

    /// Adapters are tried best first, a CPU rasteriser last, and the hardware choice
    /// (`--device auto`) never admits a CPU one: ranked any higher, lavapipe would be
    /// opened before a hardware GPU beside it, and `auto` would render slower even than
    /// the CPU path (lavapipe measured 0.1–0.4× of it by Mesa version, docs/BENCHMARKS.md).
    #[test]
    fn hardware_adapters_come_before_software_ones() {
        use wgpu::DeviceType as T;
        let mut types = [
            T::Cpu,
            T::Other,
            T::VirtualGpu,
            T::IntegratedGpu,
            T::DiscreteGpu,
        ];
        types.sort_by_key(|&t| rank(t));
        assert_eq!(
            types,
            [
                T::DiscreteGpu,
                T::IntegratedGpu,
                T::VirtualGpu,
                T::Other,
                T::Cpu
            ]
        );
        for t in types {
            let info = wgpu::AdapterInfo::new(t, wgpu::Backend::Vulkan);
            assert!(AdapterChoice::Any.admits(&info), "{t:?}");
            assert_eq!(AdapterChoice::Hardware.admits(&info), t != T::Cpu, "{t:?}");
        }
    }

    /// wgpu's multi-line error text becomes one line, its blank lines and indents gone.
    #[test]
    fn gpu_errors_fit_on_one_line() {
        let text = "Validation Error\n\nCaused by:\n  In Device::create_buffer\n    \
                    Usages contain both MAP_READ and STORAGE\n";
        assert_eq!(
            one_line(text),
            "Validation Error Caused by: In Device::create_buffer Usages contain both \
             MAP_READ and STORAGE"
        );
    }

    /// The reason names the fix that applies: `--device gpu` where a software adapter
    /// exists, installing lavapipe where none does. (Backends are given, so that
    /// `WGPU_BACKEND` in the environment plays no part.)
    #[test]
    fn no_adapter_names_the_fix_that_applies() {
        let vk = Some(wgpu::Backends::VULKAN);
        let lvp = ["llvmpipe (LLVM 15.0.6, 256 bits)".to_string()];
        let m = no_adapter(AdapterChoice::Hardware, vk, &lvp, &[]);
        assert!(
            m.contains("--device gpu would use the software adapter llvmpipe"),
            "{m}"
        );
        let m = no_adapter(AdapterChoice::Hardware, vk, &[], &[]);
        assert!(
            m.starts_with("no GPU adapter") && !m.contains("--device gpu"),
            "{m}"
        );
        let m = no_adapter(AdapterChoice::Any, vk, &[], &[]);
        assert!(m.contains("apt-get install mesa-vulkan-drivers"), "{m}");
        assert!(m.contains("--device cpu"), "{m}");
    }
}
