//! The bands of image rows a GPU render dispatches one after another: how many path
//! slots a dispatch may cover, and the workgroups and tile order of each band.

use crate::error::RenderError;

use super::context::GpuContext;
use super::kernels::{self, KernelShape};

/// The most path slots a software adapter's dispatch covers (more render in bands): lavapipe
/// on 2 cores runs 65,536 ST-CVAE paths in ~1 s, PT's in ~5 s (k = 1, 2026-11-27). A
/// dispatch cannot be interrupted, so this bounds how long a stop request waits.
const SOFTWARE_BAND_SLOTS: u64 = 1 << 16;

/// The most path slots a hardware GPU's dispatch covers. A band was as large as a storage
/// binding allows: 16.8 M slots for a 4096² PT render, 16× the 2^20 invocations that the
/// bounce budget's "far below watchdogs" was reckoned for (an H100's PT at k = 8, ~10⁹
/// events/s, would take ~4 s a dispatch, beyond Windows' 2 s watchdog, and a stop request
/// would wait as long).
pub(super) const HARDWARE_BAND_SLOTS: u64 = 1 << 22;

/// The most path slots a dispatch covers: a `software` or hardware adapter's cap
/// ([`SOFTWARE_BAND_SLOTS`], [`HARDWARE_BAND_SLOTS`]), or less where the test hook
/// [`KernelShape::band_slots`] (`hook`) asks.
pub(super) fn band_cap(software: bool, hook: Option<u32>) -> u64 {
    let cap = if software {
        SOFTWARE_BAND_SLOTS
    } else {
        HARDWARE_BAND_SLOTS
    };
    hook.map_or(cap, |n| cap.min(n as u64))
}

/// Rows of `row_slots` path slots a band holds: what one binding of `fit` slots takes, at
/// most the image's `height`, and no more than the per-dispatch `cap` ([`band_cap`])
/// allows but one row; 0 where not even a row fits a binding.
fn band_rows(fit: u64, row_slots: u64, height: u32, cap: u64) -> u32 {
    let rows = fit / row_slots;
    rows.min((cap / row_slots).max(1)).min(height as u64) as u32
}

/// Invocations a dispatch aims to have in flight: a big GPU needs ~10⁶ to be busy; a
/// software adapter gains nothing beyond a few per core.
pub(super) fn target_threads(ctx: &GpuContext) -> u64 {
    if ctx.adapter.software {
        1 << 12
    } else {
        1 << 20
    }
}

/// The stride of the workgroup → tile permutation (shaders/path.wgsl, render_main): near
/// n·(√5 − 1)/2, so consecutive workgroups land far apart, and coprime with n, so the map
/// w ↦ w·P mod n is a bijection. Kept below 2^24 to travel exactly as an f32.
fn tile_stride(n: u64) -> u64 {
    fn gcd(a: u64, b: u64) -> u64 {
        if b == 0 { a } else { gcd(b, a % b) }
    }
    if n <= 2 {
        return 1;
    }
    let mut p = ((n as f64 * 0.618_034) as u64).clamp(1, (1 << 24) - 1);
    while gcd(p, n) != 1 {
        p -= 1;
    }
    p
}

/// One band of rows of the image: its first row and count, its workgroups and the stride
/// of their scattered order, and its accumulation buffer (index and size).
pub(super) struct Band {
    pub(super) index: usize,
    pub(super) row0: u32,
    pub(super) rows: u32,
    pub(super) groups: (u32, u32),
    pub(super) stride: f32,
    pub(super) bytes: u64,
}

/// The bands of rows an image is rendered in, one after another within every chunk of
/// samples, each with its own accumulation buffer of `slot_bytes` a path slot (`lanes`
/// slots a pixel), at most `cap` slots a band ([`band_cap`]). An image whose slots exceed
/// one binding (`fit` slots; lavapipe's 128 MiB holds 0.76–1.2 M pixels, 0.6–0.84 M with
/// the variance's squares) takes several. Seeds follow the pixel's index in the image, so
/// a band renders what the whole image would. A software adapter also bands an image of
/// more than
/// [`SOFTWARE_BAND_SLOTS`] slots, so that a dispatch stays short enough for a stop
/// request, answered between dispatches, to be answered within seconds.
pub(super) fn plan_bands(
    ctx: &GpuContext,
    cam: &crate::camera::Camera,
    lanes: u32,
    (fit, cap): (u64, u64),
    binding_bytes: u64,
    slot_bytes: u64,
    shape: &KernelShape,
) -> Result<Vec<Band>, RenderError> {
    let row_slots = cam.width as u64 * lanes as u64;
    let band_rows = band_rows(fit, row_slots, cam.height, cap);
    if band_rows == 0 {
        return Err(RenderError::SceneBeyondGpu(format!(
            "one row of {} pixels needs {} bytes of path state, over {}'s storage binding \
             limit of {} bytes; use --device cpu",
            cam.width,
            cam.width as u64 * binding_bytes,
            ctx.adapter.name,
            ctx.limits.max_storage_buffer_binding_size
        )));
    }
    (0..cam.height)
        .step_by(band_rows as usize)
        .enumerate()
        .map(|(index, row0)| {
            let rows = band_rows.min(cam.height - row0);
            let threads = cam.width as u64 * rows as u64 * lanes as u64;
            // Workgroups as (x, y): rows of `dispatch_row` (65,535, the most a dimension
            // allows, unless a test lowers it).
            let groups = threads.div_ceil(shape.workgroup as u64);
            let row = shape.dispatch_row as u64;
            let grid = if groups <= row {
                (groups as u32, 1)
            } else {
                (row as u32, groups.div_ceil(row))
            };
            if grid.1 > kernels::DISPATCH_ROW as u64 {
                return Err(RenderError::Gpu(format!(
                    "a band of {groups} workgroups takes {} rows of {row} \
                     (STCVAE_GPU_TEST_DISPATCH_ROW), over the {} a dispatch allows",
                    grid.1,
                    kernels::DISPATCH_ROW
                )));
            }
            Ok(Band {
                index,
                row0,
                rows,
                groups: (grid.0, grid.1 as u32),
                stride: tile_stride(groups) as f32,
                bytes: threads * slot_bytes,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bands_are_capped_per_dispatch() {
        // A 4096² image at one lane a pixel, a 2 GiB binding of 112-byte slots: one band of
        // every row before the cap; now 1,024 rows (4 M slots) a band.
        let fit = ((1u64 << 31) - 1) / 112;
        let (hard, soft) = (HARDWARE_BAND_SLOTS, SOFTWARE_BAND_SLOTS);
        assert_eq!(band_rows(fit, 4096, 4096, hard), 1024);
        assert_eq!(band_rows(fit, 4096, 4096, soft), 16);
        // A binding smaller than the cap decides; a row wider than the cap is a band alone;
        // a short image is one band; no row fits: 0.
        assert_eq!(band_rows(1 << 20, 4096, 4096, hard), 256);
        assert_eq!(band_rows(fit, 1 << 23, 4096, hard), 1);
        assert_eq!(band_rows(fit, 4096, 100, hard), 100);
        assert_eq!(band_rows(100, 4096, 4096, hard), 0);
        // Each kind of adapter its own cap; the test hook only lowers it.
        assert_eq!((band_cap(false, None), band_cap(true, None)), (hard, soft));
        assert_eq!(band_cap(true, Some(1536)), 1536);
        assert_eq!(band_cap(true, Some(1 << 22)), soft);
        assert_eq!(band_cap(false, Some(1 << 22)), hard);
    }
}
