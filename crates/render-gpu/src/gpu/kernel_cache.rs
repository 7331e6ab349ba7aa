//! Kernels compiled for a device's earlier renders, kept for its later ones. Building a
//! render's pipelines (naga's parse, validation and SPIR-V of the kernel source, and the
//! driver's pipeline) took 1.2–2.3 s a render on lavapipe (2 cores, Mesa 22, 2026-12-07;
//! docs/BENCHMARKS.md) even for a kernel built moments before, which a test or an
//! experiment rendering the same scene for many seeds paid every time; a kept pipeline
//! also skips llvmpipe's compile at the first dispatch (renderer.rs, `compile`). A
//! pipeline is found again by everything it is built from: the WGSL source (the scene
//! switches, the model's sizes and the kernel shape are baked into it), the entry point
//! and the bind-group layout.

use std::collections::VecDeque;
use std::sync::Mutex;

use crate::error::RenderError;

/// Pipelines kept: more distinct kernels than one process renders with, but for the test
/// binaries (a pipeline holds its compiled code: on lavapipe a few MB).
pub const MOST_PIPELINES: usize = 16;

/// The bind-group layouts of the kernels ([`super::kernels::bind_group_layout`],
/// [`super::kernels::args_layout`]), made once, so that a pipeline's layout is the same
/// handle render after render (wgpu compares handles, not their entries).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayoutKind {
    Single,
    Staged,
    Arguments,
}

struct Kept<L, P> {
    layout: L,
    entry: String,
    source: String,
    pipeline: P,
}

/// The cache: layouts by kind, and the [`MOST_PIPELINES`] pipelines used last. Generic so
/// that its bookkeeping is tested without a device; the renderer's holds wgpu's handles.
pub struct KernelCache<L = wgpu::BindGroupLayout, P = wgpu::ComputePipeline> {
    layouts: Mutex<Vec<(LayoutKind, L)>>,
    pipelines: Mutex<VecDeque<Kept<L, P>>>,
    /// Pipelines found (hits) and built (misses), for the tests.
    counts: Mutex<(u64, u64)>,
}

impl<L, P> Default for KernelCache<L, P> {
    fn default() -> Self {
        Self {
            layouts: Mutex::default(),
            pipelines: Mutex::default(),
            counts: Mutex::default(),
        }
    }
}

impl<L: Clone + PartialEq, P: Clone> KernelCache<L, P> {
    /// The layout of `kind`, made by `make` the first time.
    pub fn layout(&self, kind: LayoutKind, make: impl FnOnce() -> L) -> L {
        let mut layouts = self.layouts.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, l)) = layouts.iter().find(|(k, _)| *k == kind) {
            return l.clone();
        }
        let l = make();
        layouts.push((kind, l.clone()));
        l
    }

    /// The pipeline of `entry` in `source` on `layout`: a kept one, or the one `build`
    /// makes, kept if it built (an error is returned and nothing kept). The lock is held
    /// while building, so that two threads asking for one kernel build it once.
    pub fn pipeline(
        &self,
        layout: &L,
        entry: &str,
        source: String,
        build: impl FnOnce(&str) -> Result<P, RenderError>,
    ) -> Result<P, RenderError> {
        let mut kept = self.pipelines.lock().unwrap_or_else(|e| e.into_inner());
        let found = kept
            .iter()
            .position(|k| k.entry == entry && k.layout == *layout && k.source == source);
        let mut counts = self.counts.lock().unwrap_or_else(|e| e.into_inner());
        if found.is_some() {
            counts.0 += 1;
        } else {
            counts.1 += 1;
        }
        // Not held while building, so that `counts` answers meanwhile.
        drop(counts);
        if let Some(i) = found {
            // Used last: kept longest.
            let k = kept.remove(i).expect("a found index");
            let p = k.pipeline.clone();
            kept.push_back(k);
            return Ok(p);
        }
        let pipeline = build(&source)?;
        if kept.len() == MOST_PIPELINES {
            kept.pop_front();
        }
        kept.push_back(Kept {
            layout: layout.clone(),
            entry: entry.to_owned(),
            source,
            pipeline: pipeline.clone(),
        });
        Ok(pipeline)
    }

    /// Pipelines found kept and pipelines built so far.
    pub fn counts(&self) -> (u64, u64) {
        *self.counts.lock().unwrap_or_else(|e| e.into_inner())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A kernel is found again only by its source, entry point and layout together; the
    /// [`MOST_PIPELINES`] used last are kept, a hit counting as a use; a failed build is
    /// returned and not kept; layouts are made once a kind.
    #[test]
    fn pipelines_are_kept_by_source_entry_and_layout() {
        let cache = KernelCache::<u8, u32>::default();
        let built = std::cell::Cell::new(0u32);
        let get = |layout: u8, entry: &str, source: &str| {
            cache
                .pipeline(&layout, entry, source.to_owned(), |_| {
                    built.set(built.get() + 1);
                    Ok(built.get())
                })
                .unwrap()
        };
        let first = get(0, "main", "a");
        assert_eq!(get(0, "main", "a"), first);
        // Each part of the key alone tells kernels apart.
        let others = [
            get(1, "main", "a"),
            get(0, "other", "a"),
            get(0, "main", "b"),
        ];
        assert_eq!(others, [2, 3, 4]);
        assert_eq!(cache.counts(), (1, 4));
        // Fill up: "a"/main is used again after 12 more kernels (16 kept), then 3 more
        // evict the three built after it, not it (a hit counts as a use).
        for n in 0..12 {
            get(0, "main", &format!("fill {n}"));
        }
        assert_eq!(get(0, "main", "a"), first);
        for n in 12..15 {
            get(0, "main", &format!("fill {n}"));
        }
        // "b", built 4th, was the third of them: 16 are kept, not 17.
        assert_eq!(get(0, "main", "b"), built.get(), "\"b\" was kept");
        let (hits, misses) = cache.counts();
        assert_eq!(
            get(0, "main", "a"),
            first,
            "the kernel used last was evicted"
        );
        assert_eq!(cache.counts(), (hits + 1, misses));
        // The first the fills evicted (built 2nd, layout 1) is built again.
        assert_eq!(get(1, "main", "a"), built.get());
        assert_eq!(cache.counts(), (hits + 1, misses + 1));
        // A failed build is returned, and nothing kept: asked again, it builds again.
        let fail = |source: &str| {
            cache.pipeline(&0, "main", source.to_owned(), |_| {
                built.set(built.get() + 1);
                Err(RenderError::Gpu("did not compile".into()))
            })
        };
        assert!(fail("broken").is_err());
        let before = built.get();
        assert!(fail("broken").is_err());
        assert_eq!(built.get(), before + 1);
        // Layouts: made once a kind.
        let made = std::cell::Cell::new(0u8);
        let layout = |kind| {
            cache.layout(kind, || {
                made.set(made.get() + 1);
                made.get()
            })
        };
        assert_eq!(layout(LayoutKind::Single), 1);
        assert_eq!(layout(LayoutKind::Staged), 2);
        assert_eq!(layout(LayoutKind::Single), 1);
        assert_eq!(layout(LayoutKind::Arguments), 3);
        assert_eq!(made.get(), 3);
    }
}
