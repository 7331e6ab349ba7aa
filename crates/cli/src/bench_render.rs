//! `stcvae bench render`: the authors' teaser ladder, PT vs ST-CVAE side by side.
//!
//! Each integrator renders the same image twice with independent seeds (half the spp
//! each). The halves give every pixel's variance of the mean, Var ≈ (A₁ − A₂)²/4, so
//! the bias RMSE can be corrected for noise: RMSE² = mean((A − B)²) − mean(Var_A + Var_B).
//! Images are scaled so that the 99th percentile of PT's object pixels is 1.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use anyhow::Result;
use render_gpu::image_io::RgbImage;
use render_gpu::integrator::{IntegratorKind, IntegratorSettings, PathStats};
use render_gpu::render::RenderOptions;

use crate::device::{DeviceArg, Engine};
use crate::render::prepare;

#[derive(clap::Args)]
pub struct Args {
    /// Scene the ladder scales (its σ_t is replaced by k·(150, 187.5, 125)).
    #[arg(long, default_value = "configs/scenes/bunny.toml")]
    scene: PathBuf,
    /// Density multipliers.
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,8")]
    k: Vec<f64>,
    /// Samples per pixel of each integrator (split over two seeds).
    #[arg(long, default_value_t = 16)]
    spp: u32,
    /// Image side in pixels.
    #[arg(long, default_value_t = 64)]
    size: u32,
    #[arg(long)]
    model: Option<PathBuf>,
    /// Thin-region threshold of ST-CVAE (overrides the scene's).
    #[arg(long)]
    min_tau: Option<f64>,
    /// Largest sphere step of ST-CVAE (overrides the scene's).
    #[arg(long)]
    max_tau: Option<f64>,
    /// Representative events per sphere step for NEE (overrides the scene's).
    #[arg(long)]
    nee_samples: Option<u32>,
    /// Where both integrators run: auto, gpu (any wgpu adapter) or cpu.
    #[arg(long, value_enum, default_value_t = DeviceArg::Cpu)]
    device: DeviceArg,
}

struct Run {
    a: RgbImage,
    b: RgbImage,
    seconds: f64,
    stats: PathStats,
}

fn run_pair(a: &Args, engine: &Engine, kind: IntegratorKind, k: f64) -> Result<Run> {
    let p = prepare(&a.scene, Some(kind), Some(true), a.model.as_deref(), |f| {
        f.medium.sigma_t = [150.0 * k, 187.5 * k, 125.0 * k];
        f.medium.albedo = [0.99999, 0.99995, 0.975];
        f.medium.g = 0.875;
        f.camera.width = a.size;
        f.camera.height = a.size;
        if let Some(t) = a.min_tau {
            f.render.min_tau = t;
        }
        if a.max_tau.is_some() {
            f.render.max_tau = a.max_tau;
        }
        if let Some(m) = a.nee_samples {
            f.render.nee_samples = m;
        }
    })?;
    let set = IntegratorSettings {
        kind,
        nee: true,
        model: p.model.as_ref(),
        min_tau: p.file.render.min_tau as f32,
        max_tau: p.max_tau,
        nee_samples: p.file.render.nee_samples,
    };
    let cancel = AtomicBool::new(false);
    let half = (a.spp / 2).max(1);
    let mut stats = PathStats::default();
    let mut seconds = 0.0;
    let mut imgs = Vec::new();
    if matches!(engine, Engine::Gpu(_)) {
        // Warm-up: the first dispatch compiles the kernel; keep it out of the timing.
        let tiny = RenderOptions {
            spp: 1,
            seed: 1,
            time_budget: None,
        };
        engine.render(&p.data, &set, &tiny, &|_, _| {}, &cancel)?;
    }
    for seed in [11, 12] {
        let o = engine.render(
            &p.data,
            &set,
            &RenderOptions {
                spp: half,
                seed,
                time_budget: None,
            },
            &|_, _| {},
            &cancel,
        )?;
        seconds += o.seconds;
        stats.add(&o.stats);
        imgs.push(o.image);
    }
    let b = imgs.pop().unwrap();
    let a_img = imgs.pop().unwrap();
    Ok(Run {
        a: a_img,
        b,
        seconds,
        stats,
    })
}

fn lum(p: [f32; 3]) -> f64 {
    (p[0] + p[1] + p[2]) as f64 / 3.0
}

/// Per-pixel mean of the two halves and variance of that mean, all channels.
fn mean_var(r: &Run) -> (Vec<f64>, Vec<f64>) {
    let mut m = Vec::new();
    let mut v = Vec::new();
    for (x, y) in r.a.pixels.iter().zip(&r.b.pixels) {
        for c in 0..3 {
            let (x, y) = (x[c] as f64, y[c] as f64);
            m.push(0.5 * (x + y));
            v.push(0.25 * (x - y) * (x - y));
        }
    }
    (m, v)
}

pub fn run(a: Args) -> Result<()> {
    let engine = Engine::open(a.device)?;
    println!(
        "stcvae bench render: {} ({}x{}), g = 0.875, albedo (0.99999, 0.99995, 0.975), NEE on, {} spp each (2 seeds), {}",
        a.scene.display(),
        a.size,
        a.size,
        a.spp,
        engine.describe()
    );
    println!(
        "{:>4} {:>20} {:>7} {:>7} {:>9} {:>9} {:>11} {:>10} {:>10} {:>10} {:>9} {:>9} {:>10} {:>10}",
        "k",
        "sigma_t",
        "PT s",
        "ST s",
        "speed-up",
        "var ratio",
        "equal-error",
        "PT ev/path",
        "ST st/path",
        "ST ev/path",
        "bias RMSE",
        "noise",
        "PT paths/s",
        "ST paths/s"
    );
    for &k in &a.k {
        let pt = run_pair(&a, &engine, IntegratorKind::Pt, k)?;
        let st = run_pair(&a, &engine, IntegratorKind::Stcvae, k)?;
        let (mp, vp) = mean_var(&pt);
        let (ms, vs) = mean_var(&st);
        // Scale: the 99th percentile of PT's object pixels (luminance above 1e-3 of max).
        let mut l: Vec<f64> =
            pt.a.pixels
                .iter()
                .zip(&pt.b.pixels)
                .map(|(x, y)| 0.5 * (lum(*x) + lum(*y)))
                .collect();
        let max = l.iter().cloned().fold(0.0, f64::max);
        l.retain(|&v| v > 1e-3 * max);
        l.sort_by(f64::total_cmp);
        let scale = if l.is_empty() {
            1.0
        } else {
            1.0 / l[(l.len() * 99 / 100).min(l.len() - 1)].max(1e-12)
        };
        let n = mp.len() as f64;
        let mse: f64 = mp
            .iter()
            .zip(&ms)
            .map(|(x, y)| (x - y).powi(2))
            .sum::<f64>()
            / n;
        let noise: f64 = vp.iter().zip(&vs).map(|(x, y)| x + y).sum::<f64>() / n;
        let bias = (mse - noise).max(0.0).sqrt() * scale;
        let var_ratio = vp.iter().sum::<f64>() / vs.iter().sum::<f64>().max(1e-300);
        let speed = pt.seconds / st.seconds;
        println!(
            "{:>4} {:>20} {:>7.2} {:>7.2} {:>8.2}x {:>9.2} {:>10.2}x {:>10.1} {:>10.2} {:>10.2} {:>9.4} {:>9.4} {:>10} {:>10}",
            k,
            format!("({}, {}, {})", 150.0 * k, 187.5 * k, 125.0 * k),
            pt.seconds,
            st.seconds,
            speed,
            var_ratio,
            speed * var_ratio,
            pt.stats.events as f64 / pt.stats.paths.max(1) as f64,
            st.stats.steps as f64 / st.stats.paths.max(1) as f64,
            st.stats.events as f64 / st.stats.paths.max(1) as f64,
            bias,
            noise.sqrt() * scale,
            crate::progress::si(pt.stats.paths as f64 / pt.seconds.max(1e-9)),
            crate::progress::si(st.stats.paths as f64 / st.seconds.max(1e-9))
        );
        if st.stats.leaks > 0 {
            println!("     ({} leaked sphere exits)", st.stats.leaks);
        }
    }
    println!(
        "speed-up = PT time / ST-CVAE time at equal spp; var ratio = PT variance / ST-CVAE variance; \
         equal-error = their product (time ratio to reach the same noise); bias RMSE is noise-corrected, \
         images scaled so PT's brightest 1% of object pixels is 1"
    );
    let _ = Path::new("");
    Ok(())
}
