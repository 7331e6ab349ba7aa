//! `stcvae render`'s command line: its flags and the parsers that check their ranges.

use std::path::PathBuf;

use render_gpu::integrator::IntegratorKind;

use crate::device::DeviceArg;

use super::DEFAULT_SCENE;

#[derive(clap::Args)]
#[command(
    after_help = "With no arguments renders the shipped bunny scene with the shipped \
    model to out/render.{exr,png,json}. Options given here override the scene's [render] table.\n\n\
    Example:\n  stcvae render --scene configs/scenes/sphere.toml --integrator pt --spp 256 --out out/sphere_pt\n  \
    stcvae render configs/scenes/sphere.toml --width 128 --spp 16   (a quick look: 128 pixels wide)"
)]
pub struct Args {
    /// Scene file (TOML; the format is in the README).
    #[arg(long, default_value = DEFAULT_SCENE, value_parser = crate::shipped::scene_arg(DEFAULT_SCENE))]
    pub scene: PathBuf,
    /// The scene file, given without --scene (`stcvae render S.toml`).
    #[arg(value_name = "SCENE", conflicts_with = "scene",
          value_parser = crate::shipped::scene_arg(DEFAULT_SCENE))]
    pub scene_file: Option<PathBuf>,
    /// Image width in pixels, 1 to 16384 (overrides camera.width; given alone, the height
    /// follows the camera's aspect).
    #[arg(long, allow_negative_numbers = true,
          value_parser = crate::whole::whole::<u32>(1, render_gpu::scene::MAX_IMAGE_SIDE as u64))]
    pub width: Option<u32>,
    /// Image height in pixels, 1 to 16384 (overrides camera.height; given alone, the width
    /// follows the camera's aspect).
    #[arg(long, allow_negative_numbers = true,
          value_parser = crate::whole::whole::<u32>(1, render_gpu::scene::MAX_IMAGE_SIDE as u64))]
    pub height: Option<u32>,
    /// pt (volumetric path tracing, the reference) or stcvae (sphere tracing with the CVAEs)
    /// (overrides render.integrator).
    #[arg(long, value_parser = integrator_parser())]
    pub integrator: Option<IntegratorKind>,
    /// Next-event estimation to the directional lights, true or false (overrides
    /// render.nee).
    #[arg(long)]
    pub nee: Option<bool>,
    /// Samples per pixel, 1 to 2³² − 1 (overrides render.spp).
    #[arg(long, allow_negative_numbers = true, value_parser = crate::whole::whole::<u32>(1, u32::MAX.into()))]
    pub spp: Option<u32>,
    /// Random seed, an integer in [0, 2^64) (overrides render.seed): renders with different
    /// seeds are independent and can be averaged with `stcvae merge`.
    #[arg(long, allow_negative_numbers = true, value_parser = parse_seed)]
    pub seed: Option<u64>,
    /// Model file for stcvae (default: models/default.stcvae).
    #[arg(long, value_parser = crate::shipped::model_arg)]
    pub model: Option<PathBuf>,
    /// Stop after the pass during which this many seconds have passed, in (0, 1e8] (over
    /// three years; the JSON and the EXR header record the spp actually rendered; at least
    /// one pass runs).
    /// The scene's spp is then no limit; --spp given too stops at that many first.
    #[arg(long, allow_negative_numbers = true, value_parser = parse_time_budget)]
    pub time_budget: Option<f64>,
    /// Output path without extension: writes OUT.exr, OUT.png and OUT.json (a typed .exr,
    /// .png or .json is dropped: `--out a.exr` writes a.exr, a.png, a.json).
    #[arg(long, default_value = "out/render")]
    pub out: PathBuf,
    /// Where to render: auto (a hardware GPU if there is one, else the CPU), gpu (any
    /// wgpu adapter, software ones such as lavapipe included) or cpu.
    #[arg(long, value_enum, default_value_t = DeviceArg::Auto)]
    pub device: DeviceArg,
    /// Exposure multiplier of the PNG preview, > 0 (the EXR is always linear and
    /// unscaled).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1.0, value_parser = parse_exposure)]
    pub exposure: f32,
    /// Also write OUT.var.exr: per pixel and channel the estimated variance of the
    /// pixel's value (its squared standard error, from the samples' own spread), on
    /// either device, from 6 spp on. A render without it removes an older OUT.var.exr, which would no
    /// longer belong to OUT.exr.
    #[arg(long)]
    pub variance: bool,
}

/// `--seed`: clap's own u64 parser said only "invalid digit found in string" for -1.
pub fn parse_seed(s: &str) -> Result<u64, String> {
    crate::whole::whole(0, u64::MAX)(s)
}

/// `--exposure`: a positive number that stays positive and finite as the f32 the PNG
/// encoder scales by. Parsed as f64 first so that the message quotes what was typed
/// (clap's own f32 parser turned 1e-300 into 0 and the message said "--exposure 0").
pub(crate) fn parse_exposure(s: &str) -> Result<f32, String> {
    let x: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a number"))?;
    let e = x as f32;
    if x > 0.0 && e > 0.0 && e.is_finite() {
        Ok(e)
    } else {
        Err(format!(
            "{} is out of range: must be > 0 and finite as an f32, i.e. in [{:e}, {:e}]",
            s.trim(),
            f32::from_bits(1),
            f32::MAX
        ))
    }
}

/// `--time-budget`: clap's own f64 parser said only "invalid float literal", with no range;
/// and 1e300 was taken (a render without end, announced with 300 digits).
fn parse_time_budget(s: &str) -> Result<f64, String> {
    let b: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a number of seconds"))?;
    if b > 0.0 && b <= MAX_TIME_BUDGET {
        Ok(b)
    } else {
        Err(format!(
            "{} is out of range: allowed (0, {MAX_TIME_BUDGET:e}] seconds",
            s.trim()
        ))
    }
}

/// Longest `--time-budget`, in seconds (over three years).
const MAX_TIME_BUDGET: f64 = 1e8;

/// `--integrator`: pt or stcvae (st-cvae accepted too), listed in the help.
fn integrator_parser() -> impl clap::builder::TypedValueParser<Value = IntegratorKind> {
    use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser as _};
    PossibleValuesParser::new([
        PossibleValue::new("pt"),
        PossibleValue::new("stcvae").alias("st-cvae"),
    ])
    .map(|s| match s.as_str() {
        "pt" => IntegratorKind::Pt,
        _ => IntegratorKind::Stcvae,
    })
}

#[cfg(test)]
mod tests {
    use super::parse_exposure;

    #[test]
    fn exposure_takes_positive_finite_f32s_and_quotes_what_was_typed() {
        for (ok, want) in [
            ("1", 1.0f32),
            (" 0.25 ", 0.25),
            ("3e38", 3e38),
            ("1e-45", 1e-45),
        ] {
            assert_eq!(parse_exposure(ok), Ok(want), "{ok}");
        }
        for bad in ["0", "-1", "NaN", "inf", "1e39", "x"] {
            assert!(parse_exposure(bad).is_err(), "{bad}");
        }
        // Below f32's smallest subnormal the f32 would be 0: refused, naming the input.
        let e = parse_exposure("1e-300").unwrap_err();
        assert!(e.starts_with("1e-300 is out of range"), "{e}");
    }

    /// The help's image sizes are the scene file's limit (doc comments cannot name it).
    #[test]
    fn the_help_gives_the_image_size_limit() {
        use clap::CommandFactory as _;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            a: super::Args,
        }
        let cmd = Cli::command();
        let range = format!("1 to {}", render_gpu::scene::MAX_IMAGE_SIDE);
        for id in ["width", "height"] {
            let help = crate::help_of(&cmd, id);
            assert!(help.contains(&range), "--{id}: {help}");
        }
    }
}
