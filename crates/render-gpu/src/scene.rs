//! The scene file (TOML): the user-facing contract, documented in the README.
//!
//! Parsing rejects unknown keys; [`SceneFile::validate`] checks every range and names the
//! offending field, so a bad file never reaches the integrators.

use std::path::{Path, PathBuf};

use scatter_sim::ranges::{self, num, printable};
use serde::{Deserialize, Serialize};

use crate::error::RenderError;

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub camera: CameraDesc,
    pub object: ObjectDesc,
    pub medium: MediumDesc,
    #[serde(default)]
    pub boundary: BoundaryDesc,
    #[serde(default, rename = "light")]
    pub lights: Vec<LightDesc>,
    #[serde(default)]
    pub environment: EnvironmentDesc,
    #[serde(default)]
    pub render: RenderDesc,
}

/// Pinhole camera; (target − origin) × up points to the right of the image, row 0 is
/// the top row (Mitsuba's convention).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CameraDesc {
    #[serde(deserialize_with = "triple")]
    pub origin: [f64; 3],
    #[serde(deserialize_with = "triple")]
    pub target: [f64; 3],
    #[serde(default = "default_up", deserialize_with = "triple")]
    pub up: [f64; 3],
    /// Horizontal field of view, degrees.
    pub fov_deg: f64,
    #[serde(deserialize_with = "whole::<W_WIDTH, _>")]
    pub width: u32,
    #[serde(deserialize_with = "whole::<W_HEIGHT, _>")]
    pub height: u32,
}

/// A TOML error as `FILE:LINE: message (in `the line`)`, one line: a value's error (a
/// wrong type, a triple of the wrong length) does not say which key it belongs to, the
/// quoted line does. Every TOML file stcvae reads reports its errors this way.
pub fn describe_toml_error(path: &Path, text: &str, e: &toml::de::Error) -> String {
    let msg = plain_types(&printable(&e.message().trim().replace('\n', " ")));
    // A field missing from the top level is reported at the document's start, whose first
    // line (often a comment) says nothing: name the field alone.
    let top_level = e.span().is_some_and(|s| s.start == 0) && msg.starts_with("missing field");
    // A file opening with a table's header is ambiguous there: toml reports that table's
    // missing field at byte 0 too (a scene opening with [camera] and no fov_deg), and
    // `height` is a field of two tables. Both places named.
    let first = text
        .trim_start_matches('\u{feff}')
        .lines()
        .next()
        .unwrap_or("")
        .trim();
    if top_level && first.starts_with('[') {
        let shown = printable(&first.chars().take(80).collect::<String>());
        return format!(
            "{}: {msg} (at the top level or in `{shown}`)",
            path.display()
        );
    }
    let at = e.span().filter(|_| !top_level).map(|s| {
        let start = s.start.min(text.len());
        let line_start = text[..start].rfind('\n').map_or(0, |i| i + 1);
        let line = text[line_start..].lines().next().unwrap_or("").trim();
        let shown: String = printable(&line.chars().take(80).collect::<String>());
        (text[..start].matches('\n').count() + 1, shown)
    });
    match at {
        Some((l, line)) if !line.is_empty() => {
            format!("{}:{l}: {msg} (in `{line}`)", path.display())
        }
        Some((l, _)) => format!("{}:{l}: {msg}", path.display()),
        None => format!("{}: {msg}", path.display()),
    }
}

/// A field toml reports missing at the document's start, placed: a scene's top level
/// holds tables only, so a missing `[camera]`, `[object]` or `[medium]` is that table, and any
/// other field missing there belongs to the table the file opens with (toml gives both
/// the same place; [`describe_toml_error`], which serves every config, names both, and a
/// missing `[medium]` in a file opening with `[camera]` read as "missing field `medium` (at
/// the top level or in `[camera]`)"). None for any other error.
fn missing_in_scene(path: &Path, text: &str, e: &toml::de::Error) -> Option<String> {
    let field = e
        .message()
        .strip_prefix("missing field `")?
        .split('`')
        .next()?;
    if e.span()?.start != 0 {
        return None;
    }
    let table: toml::Table = text.parse().ok()?;
    if ["camera", "object", "medium"].contains(&field) && !table.contains_key(field) {
        return Some(format!(
            "{}: the table [{field}] is missing (a scene has [camera], [object] and [medium])",
            path.display()
        ));
    }
    let first = text
        .trim_start_matches('\u{feff}')
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))?;
    let name = first.strip_prefix('[')?.split(']').next()?.trim();
    table.get(name)?.as_table()?;
    Some(format!(
        "{}: missing field `{field}` in [{name}]",
        path.display()
    ))
}

/// A scene file's whole-number fields and their ranges (inclusive): `validate` checks
/// them here, and a value serde refuses for the type (negative, fractional, beyond 2^32)
/// is reported with the field's range, not the type's.
const WHOLE_FIELDS: [(&str, u32, u32); 7] = [
    ("camera.width", 1, MAX_IMAGE_SIDE),
    ("camera.height", 1, MAX_IMAGE_SIDE),
    ("render.spp", 1, u32::MAX),
    ("render.grid_resolution", 4, MAX_GRID),
    ("render.exact_nee_samples", 1, MAX_EXACT_NEE_SAMPLES),
    ("render.path_nee_rays", 0, MAX_PATH_NEE_RAYS),
    ("render.nee_samples", 1, MAX_NEE_SAMPLES),
];

const W_WIDTH: usize = 0;
const W_HEIGHT: usize = 1;
const W_SPP: usize = 2;
const W_GRID: usize = 3;
const W_EXACT_NEE_SAMPLES: usize = 4;
const W_PATH_NEE_RAYS: usize = 5;
const W_NEE_SAMPLES: usize = 6;

fn check_whole(field: usize, v: u32) -> Result<(), String> {
    let (name, lo, hi) = WHOLE_FIELDS[field];
    if (lo..=hi).contains(&v) {
        return Ok(());
    }
    Err(format!(
        "{name} = {v} is out of range: allowed {}",
        scatter_sim::ranges::whole_range(lo.into(), hi.into())
    ))
}

/// Reads one of [`WHOLE_FIELDS`] (`I` its index): a value serde would refuse for the type
/// (negative, fractional, beyond 2^32) is refused with the field's own range, not the
/// type's (`width = -1` read "expected a whole number in [0, 4294967295]"), wherever the
/// key is written (inline tables, dotted or quoted keys). A whole number of the type but
/// out of range is left to `validate`, which names the field.
fn whole<'de, const I: usize, D: serde::Deserializer<'de>>(d: D) -> Result<u32, D::Error> {
    let (_, lo, hi) = WHOLE_FIELDS[I];
    scatter_sim::ranges::whole_in(d, lo.into(), hi.into())
}

/// serde's Rust type names in words: `width = -16` said "expected u32" (and a table's
/// type, [`plain_structs`]); a refused float written short ([`short_floats`]). The field's
/// own range is checked after parsing (the validation's messages give it).
fn plain_types(msg: &str) -> String {
    let msg = &plain_structs(&short_floats(msg));
    [
        ("expected u32", "expected a whole number in [0, 4294967295]"),
        ("expected u64", "expected a whole number in [0, 2^64)"),
        ("expected usize", "expected a whole number, at least 0"),
        ("expected i64", "expected a whole number"),
        ("expected f64", "expected a number"),
        ("expected f32", "expected a number"),
    ]
    .iter()
    .fold(msg.to_string(), |m, (rust, plain)| m.replace(rust, plain))
}

/// serde names a table by the Rust type it fills ("expected struct ConditionSampler" for
/// `conditions = 5`), which the user never sees: a table it is.
fn plain_structs(msg: &str) -> String {
    rewrite_after(
        msg,
        "expected struct ",
        |c| c.is_ascii_alphanumeric() || c == '_',
        |_| "expected a table".into(),
    )
}

/// serde writes a float it refuses in full (`seed = 1e308` gave a 309-digit number):
/// written short instead, as the range messages write theirs.
fn short_floats(msg: &str) -> String {
    const TAG: &str = "floating point `";
    rewrite_after(
        msg,
        TAG,
        |c| c != '`',
        |v| match v.parse::<f64>() {
            Ok(x) if v.len() > 16 => format!("{TAG}{}", num(x)),
            _ => format!("{TAG}{v}"),
        },
    )
}

/// `msg` with each `tag` and the token after it (the characters `in_token` takes)
/// replaced by `rewrite(token)`.
fn rewrite_after(
    msg: &str,
    tag: &str,
    in_token: impl Fn(char) -> bool,
    rewrite: impl Fn(&str) -> String,
) -> String {
    let mut out = String::with_capacity(msg.len());
    let mut rest = msg;
    while let Some(i) = rest.find(tag) {
        out.push_str(&rest[..i]);
        let tail = &rest[i + tag.len()..];
        let end = tail.find(|c| !in_token(c)).unwrap_or(tail.len());
        out.push_str(&rewrite(&tail[..end]));
        rest = &tail[end..];
    }
    out.push_str(rest);
    out
}

/// Exactly three numbers. serde's own `[f64; 3]` reads the first three elements of a
/// longer TOML array and ignores the rest, so `albedo = [0.5, 0.5, 0.5, 7.0]` would pass
/// validation with its out-of-range fourth value unread.
fn triple<'de, D: serde::Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    <[f64; 3]>::try_from(v.as_slice()).map_err(|_| {
        serde::de::Error::invalid_length(v.len(), &"an array of 3 numbers (R, G, B or x, y, z)")
    })
}

fn optional_triple<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    triple(d).map(Some)
}

fn default_up() -> [f64; 3] {
    [0.0, 1.0, 0.0]
}

#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Shape {
    Sphere,
    Cube,
    /// A (2, 3) torus knot with a thin tube: the thin-featured test object (its tube is
    /// ~1/9 of its width, so sphere steps stay small there).
    #[serde(rename = "torus-knot")]
    TorusKnot,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectDesc {
    pub shape: Option<Shape>,
    /// Sphere radius (default 0.5).
    pub radius: Option<f64>,
    /// Cube edge length (default 1).
    pub size: Option<f64>,
    /// Mesh file, relative to the scene file.
    pub mesh: Option<PathBuf>,
    /// Rescale the object (mesh or shape) so its bounding-box height is this, centred at the
    /// origin.
    pub height: Option<f64>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MediumDesc {
    /// Extinction per RGB channel, 1/scene-unit.
    #[serde(deserialize_with = "triple")]
    pub sigma_t: [f64; 3],
    /// Single-scattering albedo per RGB channel.
    #[serde(deserialize_with = "triple")]
    pub albedo: [f64; 3],
    #[serde(default)]
    pub g: f64,
}

#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum BoundaryKind {
    #[default]
    IndexMatched,
    Dielectric,
}

#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BoundaryDesc {
    #[serde(default)]
    pub kind: BoundaryKind,
    /// Index of refraction of the medium (dielectric only; default [`DEFAULT_IOR`]).
    pub ior: Option<f64>,
}

/// A dielectric's index of refraction where the scene gives none.
pub const DEFAULT_IOR: f64 = 1.5;

impl BoundaryDesc {
    pub fn ior_or_default(&self) -> f64 {
        self.ior.unwrap_or(DEFAULT_IOR)
    }
}

#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum LightKind {
    Directional,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LightDesc {
    pub kind: LightKind,
    /// The direction the light travels.
    #[serde(deserialize_with = "triple")]
    pub direction: [f64; 3],
    /// Irradiance on a plane perpendicular to the light.
    #[serde(deserialize_with = "triple")]
    pub irradiance: [f64; 3],
    /// Angular diameter of the sun disk; 0 = a delta light.
    #[serde(default)]
    pub angular_diameter_deg: f64,
}

#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentDesc {
    /// Constant radiance.
    #[serde(default, deserialize_with = "optional_triple")]
    pub radiance: Option<[f64; 3]>,
    /// Lat-long EXR, relative to the scene file (multiplied by `radiance` if both given).
    pub file: Option<PathBuf>,
}

impl EnvironmentDesc {
    /// The radiance (the map's scale where there is a map) when none is given: black
    /// without a map, 1 (the map as it is) with one.
    pub fn default_radiance(&self) -> [f64; 3] {
        if self.file.is_some() {
            [1.0; 3]
        } else {
            [0.0; 3]
        }
    }

    pub fn radiance_or_default(&self) -> [f64; 3] {
        self.radiance.unwrap_or(self.default_radiance())
    }
}

#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum IntegratorKind {
    #[default]
    Pt,
    Stcvae,
}

impl IntegratorKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::Pt => "pt",
            Self::Stcvae => "stcvae",
        }
    }
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RenderDesc {
    #[serde(default)]
    pub integrator: IntegratorKind,
    #[serde(default = "yes")]
    pub nee: bool,
    #[serde(default = "default_spp", deserialize_with = "whole::<W_SPP, _>")]
    pub spp: u32,
    #[serde(default = "one")]
    pub seed: u64,
    /// Distance-grid cells along the longest side of the mesh bounds (ST-CVAE).
    #[serde(default = "default_grid", deserialize_with = "whole::<W_GRID, _>")]
    pub grid_resolution: u32,
    /// Thin-region fallback: below this optical radius σ_t·r a sphere step is replaced
    /// by an ordinary PT event (ST-CVAE). Unset: [`DEFAULT_MIN_TAU`].
    #[serde(default)]
    pub min_tau: Option<f64>,
    /// Largest optical radius of a sphere step; default: the model's training maximum.
    pub max_tau: Option<f64>,
    /// Below this optical radius a sphere step simulates its walk event by event instead
    /// of drawing it from the models: exact, and cheaper than the decoders for small
    /// balls (ST-CVAE). Unset: [`DEFAULT_EXACT_TAU`].
    #[serde(default)]
    pub exact_tau: Option<f64>,
    /// Representative events (EventGen draws) per model-drawn sphere step for NEE
    /// (ST-CVAE). 2 by measurement (docs/BENCHMARKS.md): with one, rare paths near the
    /// lit surface dominate the variance; a second EventGen draw removed them at ~10–25 %
    /// more time.
    #[serde(
        default = "default_nee_samples",
        deserialize_with = "whole::<W_NEE_SAMPLES, _>"
    )]
    pub nee_samples: u32,
    /// NEE events per exactly simulated sphere step (below `exact_tau`), chosen among
    /// the walk's events by importance. 1 by measurement (docs/BENCHMARKS.md, fifteenth
    /// session): the importance choice already puts the event near the lit side, so a
    /// second one lowers the variance less than its shadow ray costs.
    #[serde(
        default = "default_exact_nee_samples",
        deserialize_with = "whole::<W_EXACT_NEE_SAMPLES, _>"
    )]
    pub exact_nee_samples: u32,
    /// Shadow rays per path (ST-CVAE): each chooses one of the path's NEE events by a
    /// proxy of its contribution (`integrator::nee::PathNee`); 0 casts one at every NEE
    /// event instead. 1 by measurement (docs/BENCHMARKS.md, twentieth session): 18–26 %
    /// faster than 0 at ~9 % more variance, ahead at equal error at every density of the
    /// bench ladder; PT always casts one at every event. The GPU kernels run the same
    /// estimator (shaders/nee.wgsl; on lavapipe 1 is ~28 % faster than 0).
    #[serde(
        default = "default_path_nee_rays",
        deserialize_with = "whole::<W_PATH_NEE_RAYS, _>"
    )]
    pub path_nee_rays: u32,
}

impl Default for RenderDesc {
    fn default() -> Self {
        Self {
            integrator: IntegratorKind::Pt,
            nee: true,
            spp: default_spp(),
            seed: 1,
            grid_resolution: default_grid(),
            min_tau: None,
            max_tau: None,
            exact_tau: None,
            nee_samples: default_nee_samples(),
            exact_nee_samples: default_exact_nee_samples(),
            path_nee_rays: default_path_nee_rays(),
        }
    }
}

fn yes() -> bool {
    true
}
fn one() -> u64 {
    1
}
fn default_nee_samples() -> u32 {
    2
}
fn default_exact_nee_samples() -> u32 {
    1
}
fn default_path_nee_rays() -> u32 {
    1
}
fn default_spp() -> u32 {
    64
}
fn default_grid() -> u32 {
    128
}
/// The default thin-region threshold, chosen by measurement (docs/BENCHMARKS.md, fifteenth
/// session), on the CPU and GPU alike. Balls this small are exact steps (below
/// `exact_tau`): a walk of a few events with one importance-chosen NEE event, which since
/// the fifteenth session costs less than the PT events it replaces. On the CPU bunny ladder
/// 1 renders 5–7 % faster than 2 at k = 1 and the same at k = 2–8, with the same variance;
/// 0.5 and 1.5 are within noise of 1. (When steps this small drew from the models, the
/// eighth session found 2 faster on the CPU.) On a GPU the PT events that a higher
/// threshold adds diverge from the sphere steps of neighbouring lanes (lavapipe: 2 is
/// ~10 % slower than 1). Both thresholds simulate the walk exactly, so the choice does not
/// move the image's expectation.
pub const DEFAULT_MIN_TAU: f64 = 1.0;

/// The default exact-walk threshold, chosen by measurement (docs/BENCHMARKS.md), the same
/// in the GPU kernels so that both devices run one estimator. The fourteenth session chose
/// 8 (bunny, k = 8, 16,384 spp: bias RMSE against PT 0.0077 against 0.0112 with the
/// models alone at 4; 16 and 24 were then 10–18 % slower). Since the exact walks run in
/// SIMD lanes (twenty-second session) a walk of τ ≈ 20 (~25 events) costs less than the
/// decoders' three draws: on the CPU ladder at 1,024 spp, 20 against 8 renders k = 1, 2,
/// 4, 8 6–11 % faster with the same or lower variance, and at k = 2 and 8,192 spp its bias
/// RMSE is 0 (95 % bound 0.0100; 8: 0.0038, bound 0.0149). On lavapipe the kernels' scalar
/// walks make 20 ~3 % slower than 8.
pub const DEFAULT_EXACT_TAU: f64 = 20.0;
/// Largest |g| at which ST-CVAE draws sphere steps from the models; beyond it every step's
/// walk is simulated exactly. The shipped models were trained for |g| up to 0.999, but their
/// steps were measured biased against PT beyond 0.98 on both sides. Forward (thirty-ninth
/// session, NEE off, σ_t 600, radius 0.5, 8 seeds of 128 spp each; docs/BENCHMARKS.md):
/// within 1–3.5 % and |z| < 3 at g = 0.95–0.98, then −6 % (z −4.5) at 0.985, −11 % at
/// 0.99 and +34–69 % at 0.999. Backward (forty-ninth session, NEE off, σ_t 400, the models
/// alone: exact_tau 0, 8 seeds of 256 spp): within 1.6 % (|z| ≤ 2.1) at g = −0.9 to −0.98,
/// then +3–5 % (z 2.4–5.0) at −0.985 and +9–11 % (z 6–9.5) at −0.99; a step's own
/// E[0.99^N] is −27 % at τ 25, g −0.99 (`stcvae eval --at 25,-0.99,0.99`). With the
/// default exact_tau few steps in such media came from the models (0.4–1 % at g −0.99,
/// σ_t 100–400), which is why the thirty-ninth session's renders at g → −1 looked right.
/// The exact walks cost little: a ball of optical radius τ holds ~(1 − g)τ²/2 events,
/// ≤ 900 at g ≥ 0.98 and τ ≤ 300; backward paths rarely go deep enough for long ones.
pub const MODEL_MAX_G: f64 = 0.98;
/// Largest exact-walk threshold accepted: a walk in a ball of optical radius τ has
/// ~(1 − g)τ²/2 events, and beyond this the models are far cheaper.
pub const MAX_EXACT_TAU: f64 = 50.0;
/// Most NEE events of one exactly simulated sphere step (the kernels keep one reservoir
/// slot per event).
pub const MAX_EXACT_NEE_SAMPLES: u32 = 4;
/// Largest `render.path_nee_rays` (the GPU kernel saves each reservoir with its path
/// between dispatches, two vec4s each: shaders/path.wgsl).
pub const MAX_PATH_NEE_RAYS: u32 = 2;
/// Most representative events (EventGen draws) per model-drawn sphere step.
pub const MAX_NEE_SAMPLES: u32 = 64;

impl RenderDesc {
    /// The exact-walk threshold: the scene's, else [`DEFAULT_EXACT_TAU`].
    pub fn exact_tau_or_default(&self) -> f64 {
        self.exact_tau.unwrap_or(DEFAULT_EXACT_TAU)
    }

    /// The thin-region threshold: the scene's, else [`DEFAULT_MIN_TAU`].
    pub fn min_tau_or_default(&self) -> f64 {
        self.min_tau.unwrap_or(DEFAULT_MIN_TAU)
    }

    /// "render.min_tau = v" for messages, with "(its default)" where the file leaves it
    /// out: the user would look for a line that is not there.
    pub fn min_tau_words(&self) -> String {
        let default = if self.min_tau.is_none() {
            " (its default)"
        } else {
            ""
        };
        format!(
            "render.min_tau = {}{default}",
            num(self.min_tau_or_default())
        )
    }
}

/// Largest image side accepted.
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// Largest grid resolution accepted (512³ cells of 8 bytes = 1 GiB, plus the candidate
/// lists).
pub const MAX_GRID: u32 = 512;
/// Largest magnitude of a coordinate, length or extinction in scene units. The renderers
/// work in f32 with offsets relative to the object's size; beyond this (or below its
/// inverse for lengths) values collapse or overflow there although they are finite in the
/// file's f64.
pub const MAX_SCENE_VALUE: f64 = 1e6;
/// Narrowest field of view (degrees): at 8 pixels across, neighbouring pixels' directions
/// then differ by ~3 f32 ulps (2e-7 rad); narrower, or 0 as an f32 (1e-300 was taken),
/// pixels share rays. The far-away furnace test looks through 7.5e-4°.
pub const MIN_FOV_DEG: f64 = 1e-4;
/// Smallest object dimension (radius, size, height) accepted.
pub const MIN_OBJECT_SIZE: f64 = 1e-6;
/// Largest radiance or irradiance accepted: sums over millions of samples stay finite in f32.
pub const MAX_RADIANCE: f64 = 1e12;

/// Which of stcvae's TOML files a text is, by its top-level keys (None: none of them, or
/// not TOML). Each command's loader uses it to name a file given to the wrong command,
/// where the parser would report the first unknown key.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConfigKind {
    Scene,
    Experiment,
    Training,
    Dataset,
}

impl ConfigKind {
    /// "a scene file (for `stcvae render --scene`)" and so on.
    pub fn describe(self) -> &'static str {
        match self {
            ConfigKind::Scene => "a scene file (for `stcvae render --scene`)",
            ConfigKind::Experiment => "an experiment config (for `stcvae experiment`)",
            ConfigKind::Training => "a training config (for `stcvae train --config`)",
            ConfigKind::Dataset => "a dataset config (for `stcvae generate --config`)",
        }
    }
}

pub fn config_kind(text: &str) -> Option<ConfigKind> {
    let t = text.parse::<toml::Table>().ok()?;
    if t.contains_key("camera") {
        Some(ConfigKind::Scene)
    } else if t.contains_key("kind") && t.contains_key("full") {
        Some(ConfigKind::Experiment)
    } else if t.contains_key("lengthgen") {
        Some(ConfigKind::Training)
    } else if t.contains_key("walks") && t.contains_key("conditions") {
        Some(ConfigKind::Dataset)
    } else {
        None
    }
}

impl SceneFile {
    /// Parses a scene file; errors name the file and the field.
    pub fn load(path: &Path) -> Result<Self, RenderError> {
        let text = scatter_sim::output::read_input_to_string(path)
            .map_err(|e| RenderError::io(path, format!("cannot read scene file: {e}")))?;
        Self::parse(path, &text)
    }

    /// Like [`SceneFile::load`] without [`SceneFile::validate`], for a caller that
    /// overrides fields (the command line's `--integrator`, `--spp`…) and validates the
    /// result: a check that holds for one integrator only (max_tau below min_tau leaves
    /// ST-CVAE no sphere step) must not refuse the file rendered with another.
    pub fn load_unvalidated(path: &Path) -> Result<Self, RenderError> {
        let text = scatter_sim::output::read_input_to_string(path)
            .map_err(|e| RenderError::io(path, format!("cannot read scene file: {e}")))?;
        Self::parse_unvalidated(path, &text)
    }

    pub fn parse(path: &Path, text: &str) -> Result<Self, RenderError> {
        let scene = Self::parse_unvalidated(path, text)?;
        scene
            .validate()
            .map_err(|m| RenderError::Scene(format!("{}: {m}", path.display())))?;
        Ok(scene)
    }

    fn parse_unvalidated(path: &Path, text: &str) -> Result<Self, RenderError> {
        // Another command's config given as a scene read as "unknown field `densities`" (or
        // whichever unknown key came first): say what the file is.
        if let Some(what) = config_kind(text).filter(|k| *k != ConfigKind::Scene) {
            return Err(RenderError::Scene(format!(
                "{}: {}, not a scene file (a scene has [camera], [object], [medium])",
                path.display(),
                what.describe()
            )));
        }
        toml::from_str(text).map_err(|e| {
            RenderError::Scene(
                missing_in_scene(path, text, &e)
                    .unwrap_or_else(|| describe_toml_error(path, text, &e)),
            )
        })
    }

    /// The ranges of the fields the command line can replace (`camera.width` and
    /// `height`, `render.spp`), as the file writes them: `render --width 8` rendered a
    /// file with `width = 0` that `experiment` and `bench` refuse, and a width too large
    /// for memory was refused for its memory, not its range.
    pub fn check_overridable(&self) -> Result<(), String> {
        check_whole(W_WIDTH, self.camera.width)?;
        check_whole(W_HEIGHT, self.camera.height)?;
        check_whole(W_SPP, self.render.spp)
    }

    /// Checks every range. The message names the field and the allowed range.
    pub fn validate(&self) -> Result<(), String> {
        check_camera(&self.camera)?;
        check_object(&self.object, &self.environment.file)?;
        check_medium(&self.medium)?;
        check_boundary(&self.boundary)?;
        check_lights(&self.lights)?;
        check_environment(self.environment.radiance)?;
        check_render(&self.render)
    }
}

/// The camera's vectors, basis, field of view and image size.
fn check_camera(c: &CameraDesc) -> Result<(), String> {
    bounded3("camera.origin", c.origin, MAX_SCENE_VALUE)?;
    bounded3("camera.target", c.target, MAX_SCENE_VALUE)?;
    bounded3("camera.up", c.up, MAX_SCENE_VALUE)?;
    camera_basis_f32(c)?;
    // See MIN_FOV_DEG (1e-300 was taken, and every pixel got the same ray).
    if !(c.fov_deg >= MIN_FOV_DEG && c.fov_deg < 180.0) {
        return Err(format!(
            "camera.fov_deg = {} is out of range: allowed [{MIN_FOV_DEG}, 180)",
            num(c.fov_deg)
        ));
    }
    check_whole(W_WIDTH, c.width)?;
    check_whole(W_HEIGHT, c.height)?;
    Ok(())
}

/// The object: a shape or a mesh, and the size settings that apply to it (`env_file`,
/// the environment map's name, is checked for an empty name with the mesh's).
fn check_object(o: &ObjectDesc, env_file: &Option<PathBuf>) -> Result<(), String> {
    match (o.shape, &o.mesh) {
        (Some(_), Some(_)) => {
            return Err("object: give either `shape` or `mesh`, not both".into());
        }
        (None, None) => {
            return Err(
                "object: missing `shape = \"sphere\"|\"cube\"|\"torus-knot\"` or `mesh = \"file\"`"
                    .into(),
            );
        }
        _ => {}
    }
    // An empty name would be reported as the scene's folder, or as ": cannot open".
    for (field, p) in [("object.mesh", &o.mesh), ("environment.file", env_file)] {
        if p.as_ref().is_some_and(|p| p.as_os_str().is_empty()) {
            return Err(format!("{field} = \"\" names no file: give a file name"));
        }
    }
    for (name, v) in [
        ("object.radius", o.radius),
        ("object.size", o.size),
        ("object.height", o.height),
    ] {
        if let Some(v) = v
            && !(MIN_OBJECT_SIZE..=MAX_SCENE_VALUE).contains(&v)
        {
            return Err(format!(
                "{name} = {} is out of range: allowed [{MIN_OBJECT_SIZE:e}, {MAX_SCENE_VALUE:e}]",
                num(v)
            ));
        }
    }
    if o.radius.is_some() && o.shape != Some(Shape::Sphere) {
        return Err("object.radius applies to shape = \"sphere\" only".into());
    }
    if o.size.is_some() && o.shape != Some(Shape::Cube) {
        return Err("object.size applies to shape = \"cube\" only".into());
    }
    // `height` rescales whatever the shape's own size made: given together, the size
    // would be read and then have no effect.
    for (name, v) in [("object.radius", o.radius), ("object.size", o.size)] {
        if v.is_some() && o.height.is_some() {
            return Err(format!(
                "{name} and object.height are both given: height rescales the object to \
                 its bounding-box height, so {name} would have no effect; give one of them"
            ));
        }
    }
    Ok(())
}

/// The medium's extinction, albedo and g.
fn check_medium(m: &MediumDesc) -> Result<(), String> {
    for i in 0..3 {
        let s = m.sigma_t[i];
        // Positive as the renderers' f32 too (1e-300 became 0: a channel silently
        // transparent).
        if !(s as f32 >= f32::MIN_POSITIVE && s <= MAX_SCENE_VALUE) {
            return Err(format!(
                "medium.sigma_t[{i}] = {} is out of range: allowed [{:e}, {MAX_SCENE_VALUE:e}]",
                num(s),
                f32::MIN_POSITIVE
            ));
        }
        ranges::check_albedo(&format!("medium.albedo[{i}]"), m.albedo[i])
            .map_err(|e| e.to_string())?;
    }
    ranges::check_g("medium.g", m.g).map_err(|e| e.to_string())?;
    Ok(())
}

/// The boundary's kind and index of refraction.
fn check_boundary(b: &BoundaryDesc) -> Result<(), String> {
    match b.kind {
        BoundaryKind::IndexMatched if b.ior.is_some() => {
            return Err(
                "boundary.ior applies to kind = \"dielectric\" only (index-matched means ior = 1)"
                    .into(),
            );
        }
        BoundaryKind::Dielectric => {
            let ior = b.ior_or_default();
            // Above 1 as the renderers' f32 too (1.0000000000000002 is 1 there).
            if !(ior as f32 > 1.0 && ior <= 4.0) {
                return Err(format!(
                    "boundary.ior = {} is out of range: allowed (1, 4] (as an f32: at \
                     least {})",
                    num(ior),
                    f32::from_bits(1.0f32.to_bits() + 1)
                ));
            }
        }
        _ => {}
    }
    Ok(())
}

/// Each light's direction, irradiance and disk.
fn check_lights(lights: &[LightDesc]) -> Result<(), String> {
    for (i, l) in lights.iter().enumerate() {
        bounded3(
            &format!("light[{i}].direction"),
            l.direction,
            MAX_SCENE_VALUE,
        )?;
        if unit_f32(l.direction).is_none() {
            return Err(format!(
                "light[{i}].direction = {:?} is zero or too short to normalise",
                l.direction
            ));
        }
        for (k, e) in l.irradiance.iter().enumerate() {
            if !(*e >= 0.0 && *e <= MAX_RADIANCE) {
                return Err(format!(
                    "light[{i}].irradiance[{k}] = {} is out of range: allowed [0, {MAX_RADIANCE:e}]",
                    num(*e)
                ));
            }
        }
        if !(0.0..=90.0).contains(&l.angular_diameter_deg) {
            return Err(format!(
                "light[{i}].angular_diameter_deg = {} is out of range: allowed [0, 90]",
                num(l.angular_diameter_deg)
            ));
        }
        // The disk's radiance is bounded as an environment's is: a small disk of a large
        // irradiance made radiances of ~1e21, whose squares overflowed `--variance`.
        if let Some(s2) = crate::light::disk_sin2(l) {
            for (k, e) in l.irradiance.iter().enumerate() {
                if crate::light::disk_radiance(*e, s2) > MAX_RADIANCE {
                    let most = MAX_RADIANCE * std::f64::consts::PI * s2;
                    return Err(format!(
                        "light[{i}].irradiance[{k}] = {} over a disk of \
                         angular_diameter_deg = {} is a radiance beyond {MAX_RADIANCE:e}: \
                         allowed up to {most:.4e} at this diameter (or a wider disk, or \
                         angular_diameter_deg = 0 for a delta light)",
                        num(*e),
                        num(l.angular_diameter_deg)
                    ));
                }
            }
        }
    }
    Ok(())
}

/// The environment's constant radiance.
fn check_environment(radiance: Option<[f64; 3]>) -> Result<(), String> {
    if let Some(r) = radiance {
        for (k, e) in r.iter().enumerate() {
            if !(*e >= 0.0 && *e <= MAX_RADIANCE) {
                return Err(format!(
                    "environment.radiance[{k}] = {} is out of range: allowed [0, {MAX_RADIANCE:e}]",
                    num(*e)
                ));
            }
        }
    }
    Ok(())
}

/// The render settings and thresholds.
fn check_render(r: &RenderDesc) -> Result<(), String> {
    check_whole(W_SPP, r.spp)?;
    check_whole(W_GRID, r.grid_resolution)?;
    if let Some(t) = r.min_tau
        && !(0.0..=MAX_SCENE_VALUE).contains(&t)
    {
        return Err(format!(
            "render.min_tau = {} is out of range: allowed [0, {MAX_SCENE_VALUE:e}]",
            num(t)
        ));
    }
    if let Some(t) = r.exact_tau
        && !(0.0..=MAX_EXACT_TAU).contains(&t)
    {
        return Err(format!(
            "render.exact_tau = {} is out of range: allowed [0, {MAX_EXACT_TAU}]",
            num(t)
        ));
    }
    check_whole(W_EXACT_NEE_SAMPLES, r.exact_nee_samples)?;
    check_whole(W_PATH_NEE_RAYS, r.path_nee_rays)?;
    check_whole(W_NEE_SAMPLES, r.nee_samples)?;
    // In f32, as the renderers hold it: 1e-300 is 0 there, no step at all.
    if let Some(t) = r.max_tau
        && !(t as f32 > 0.0 && t.is_finite())
    {
        return Err(format!(
            "render.max_tau = {} is out of range: allowed (0, the model's training maximum]",
            num(t)
        ));
    }
    // A cap below the threshold leaves ST-CVAE no step to take: it would be PT under
    // its name. (Without max_tau the cap is the model's training maximum, 300.)
    if let Some(t) = r.max_tau
        && r.integrator == IntegratorKind::Stcvae
        && (t as f32) < r.min_tau_or_default() as f32
    {
        return Err(format!(
            "render.max_tau = {} is below {}: no sphere step could be taken (allowed: \
             max_tau >= min_tau)",
            num(t),
            r.min_tau_words()
        ));
    }
    Ok(())
}

/// Every component finite and within ±`max`.
fn bounded3(name: &str, v: [f64; 3], max: f64) -> Result<(), String> {
    for (i, x) in v.iter().enumerate() {
        if !(x.abs() <= max) {
            return Err(format!(
                "{name}[{i}] = {} is out of range: allowed [-{max:e}, {max:e}]",
                num(*x)
            ));
        }
    }
    Ok(())
}

/// `v` normalised the way the renderers do it (in f64, then taken to f32: normalised in
/// f32, components below ~1e-21 squared to subnormals, and [3e-23, 0, -6e-23] came out
/// of unit length by 7 %, its light that much darker), or None when it collapses.
fn unit_f32(v: [f64; 3]) -> Option<glam::Vec3> {
    let u = glam::DVec3::from_array(v).normalize_or_zero().as_vec3();
    (u != glam::Vec3::ZERO && u.is_finite()).then_some(u)
}

/// The camera's basis as [`crate::camera::Camera`] builds it in f32 must be well defined:
/// values that differ in f64 can coincide in f32.
fn camera_basis_f32(c: &CameraDesc) -> Result<(), String> {
    let fwd =
        glam::DVec3::from_array(c.target).as_vec3() - glam::DVec3::from_array(c.origin).as_vec3();
    let Some(fwd) = unit_f32(fwd.as_dvec3().to_array()) else {
        return Err(format!(
            "camera.target {:?} equals camera.origin {:?} (at single precision)",
            c.target, c.origin
        ));
    };
    let Some(up) = unit_f32(c.up) else {
        return Err(format!(
            "camera.up = {:?} is zero or too short to normalise",
            c.up
        ));
    };
    // sin of the angle between them: below 1e-3 (0.06°) the image's right axis is noise.
    if fwd.cross(up).length() < 1e-3 {
        // Said with its value: it may be the default, which the file does not show.
        return Err(format!(
            "camera.up = {:?} is parallel to the viewing direction (target − origin): \
             set camera.up to a direction across the view (its default is [0, 1, 0])",
            c.up
        ));
    }
    Ok(())
}
