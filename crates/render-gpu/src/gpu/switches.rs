//! The `STCVAE_GPU_*` environment switches of the GPU render (bounces per dispatch,
//! samples per chunk, the kernels' shape, the staged render's turns), each read once and
//! refused by name outside its range.

use crate::error::RenderError;

use super::bands::HARDWARE_BAND_SLOTS;
use super::context::GpuContext;
use super::kernels::{self, KernelShape, StackMemory};

/// Bounces each invocation runs per dispatch at first. llvmpipe (lavapipe) stops a shader after
/// 65,535 loop iterations in total, counted per SIMD batch (a loop runs as long as its slowest
/// lane); the loops left in a bounce are BVH traversals and exact sphere steps' walks (~6 an
/// event), the decoders being straight-line code. 64 never ran into it on the bunny ladder; 128 is
/// 8–12 % faster but was cut off on the default bunny once chunks grew to 3 s (more lanes busy in
/// every bounce), and a scene whose exact walks are long (a large `exact_tau` with small g: ~(1 −
/// g)τ²/2 events a walk) is cut off at any budget above a few bounces. So software adapters start
/// at 128 with a snapshot of the path states before every dispatch: a dispatch that hits the limit
/// (counted by the kernel) is undone from the snapshot and redone with half the budget, down to one
/// bounce; the budget reached stays for the rest of the render. The kernel also sees a limit that
/// ran out inside a dispatch's last bounce (path.wgsl, `loop_limit_ran_out`), so at one bounce a
/// cut-off is an error, never a silently shortened path. The image does not depend on the budget,
/// bit for bit: paths resume exactly where they stopped, the free distance of an ST-CVAE path
/// included (tested; until the thirtieth session a resumed path forgot it, and its samples
/// differed). Hardware GPUs have no such limit; 256 keeps each dispatch far below watchdogs.
/// `STCVAE_GPU_BOUNCES` sets the first value.
pub(super) fn bounce_budget(ctx: &GpuContext) -> Result<u32, RenderError> {
    match env_value("STCVAE_GPU_BOUNCES") {
        None => Ok(if ctx.adapter.software { 128 } else { 256 }),
        Some(v) => parse_bounces(&v),
    }
}

/// `STCVAE_GPU_BOUNCES`' value, or the error that names its range.
fn parse_bounces(v: &str) -> Result<u32, RenderError> {
    parse_count("STCVAE_GPU_BOUNCES", v, MAX_BOUNCES, "bounces per dispatch")
}

/// `STCVAE_GPU_LANE_SAMPLES`: the samples every invocation takes per chunk, fixed. Unset, they
/// start at 1 and grow toward `TARGET_CHUNK_SECONDS` (renderer.rs) of work a chunk, so how much a
/// dispatch holds depends on the machine's speed; tests that must reach a software adapter's loop
/// limit fix it instead.
pub(super) fn fixed_lane_samples() -> Result<Option<u32>, RenderError> {
    env_value("STCVAE_GPU_LANE_SAMPLES").map_or(Ok(None), |v| parse_lane_samples(&v))
}

fn parse_lane_samples(v: &str) -> Result<Option<u32>, RenderError> {
    parse_count(
        "STCVAE_GPU_LANE_SAMPLES",
        v,
        MAX_LANE_SAMPLES,
        "samples per invocation and chunk",
    )
    .map(Some)
}

/// The kernels' shape from `STCVAE_GPU_WORKGROUP` (threads per workgroup) and
/// `STCVAE_GPU_STACK` (`workgroup` or `private`), each [`KernelShape::default`]'s when
/// unset. For measuring on hardware GPUs: the image does not depend on them. (Also the
/// test hook `STCVAE_GPU_TEST_UNWRITTEN_PIXEL`, [`KernelShape::unwritten_pixel`], which
/// makes the render fail, `STCVAE_GPU_TEST_DISPATCH_ROW`, [`KernelShape::dispatch_row`],
/// `STCVAE_GPU_TEST_CUT_OFFS`, [`KernelShape::cut_offs`], and
/// `STCVAE_GPU_TEST_BAND_SLOTS`, [`KernelShape::band_slots`].)
pub(super) fn kernel_shape() -> Result<KernelShape, RenderError> {
    let mut shape = KernelShape::default();
    if let Some(v) = env_value("STCVAE_GPU_WORKGROUP") {
        shape.workgroup = v
            .trim()
            .parse::<u32>()
            .ok()
            .filter(|n| KernelShape::WORKGROUPS.contains(n))
            .ok_or_else(|| {
                RenderError::Gpu(format!(
                    "STCVAE_GPU_WORKGROUP={v:?} is out of range: allowed {:?} threads per \
                     workgroup (unset it for the default, {})",
                    KernelShape::WORKGROUPS,
                    shape.workgroup
                ))
            })?;
    }
    // The switches: (variable, field, what 1 means).
    let switches = [
        (
            "STCVAE_GPU_PROFILE",
            &mut shape.profile,
            "count the SIMD lanes busy in each phase of the kernel",
        ),
        (
            "STCVAE_GPU_STAGED",
            &mut shape.staged,
            "render in kernels taking turns: paths to their next ray query or sphere step, \
             then the queued queries traced and steps run",
        ),
        (
            "STCVAE_GPU_STAGED_STEPS",
            &mut shape.steps,
            "the staged render runs the sphere steps in their own kernel (the default)",
        ),
        (
            "STCVAE_GPU_AGGREGATE",
            &mut shape.aggregate,
            "add to counters and queues once per subgroup where the adapter has subgroup \
             operations",
        ),
        (
            "STCVAE_GPU_STAGED_AHEAD",
            &mut shape.ahead,
            "the staged render sends each submission of turns before waiting for the last \
             one's counters (the default)",
        ),
    ];
    // An empty value is unset (the default): `STCVAE_GPU_STAGED_AHEAD=` turned a
    // default-on switch off.
    for (name, field, what) in switches {
        if let Some(v) = env_value(name) {
            *field = parse_switch(name, &v, what)?;
        }
    }
    if let Some(v) = env_value("STCVAE_GPU_TEST_UNWRITTEN_PIXEL") {
        shape.unwritten_pixel = Some(
            v.trim()
                .parse::<u32>()
                .ok()
                .filter(|&p| p < u32::MAX)
                .ok_or_else(|| {
                    RenderError::Gpu(format!(
                        "STCVAE_GPU_TEST_UNWRITTEN_PIXEL={v:?} is not a pixel index (a test \
                         hook: unset it)"
                    ))
                })?,
        );
    }
    if let Some(v) = env_value("STCVAE_GPU_TEST_DISPATCH_ROW") {
        shape.dispatch_row = v
            .trim()
            .parse::<u32>()
            .ok()
            .filter(|n| (1..=kernels::DISPATCH_ROW).contains(n))
            .ok_or_else(|| {
                RenderError::Gpu(format!(
                    "STCVAE_GPU_TEST_DISPATCH_ROW={v:?} is out of range: allowed 1 to {} \
                     workgroups a row (a test hook: unset it)",
                    kernels::DISPATCH_ROW
                ))
            })?;
    }
    if let Some(v) = env_value("STCVAE_GPU_TEST_CUT_OFFS") {
        shape.cut_offs = v
            .trim()
            .parse::<u32>()
            .ok()
            // More could never act: the budget, at most 65,535, halves to 1, where no
            // snapshot is kept, within 16 redos.
            .filter(|n| *n <= 16)
            .ok_or_else(|| {
                RenderError::Gpu(format!(
                    "STCVAE_GPU_TEST_CUT_OFFS={v:?} is out of range: allowed 0 to 16 \
                     dispatches (a test hook: unset it)"
                ))
            })?;
    }
    if let Some(v) = env_value("STCVAE_GPU_TEST_BAND_SLOTS") {
        shape.band_slots = Some(parse_count(
            "STCVAE_GPU_TEST_BAND_SLOTS",
            &v,
            HARDWARE_BAND_SLOTS as u32,
            "path slots a band, a test hook",
        )?);
    }
    if let Some(v) = env_value("STCVAE_GPU_STACK") {
        shape.stack = parse_choice(
            "STCVAE_GPU_STACK",
            &v,
            &[
                ("workgroup", StackMemory::Workgroup),
                ("private", StackMemory::Private),
            ],
            "a stack memory: allowed workgroup or private (unset it for the default, workgroup)",
        )?;
    }
    Ok(shape)
}

/// The switch `name` = `v`: 1 or true (`what`), 0, false or empty.
fn parse_switch(name: &str, v: &str, what: &str) -> Result<bool, RenderError> {
    parse_choice(
        name,
        v,
        &[("1", true), ("true", true), ("0", false), ("false", false)],
        &format!("a switch: allowed 1 or true ({what}), 0 or false, empty for the default"),
    )
}

/// The value `v` of the variable `name` among the named `choices`, or the error that says
/// it is not `what`.
fn parse_choice<T: Copy>(
    name: &str,
    v: &str,
    choices: &[(&str, T)],
    what: &str,
) -> Result<T, RenderError> {
    choices
        .iter()
        .find(|(word, _)| *word == v.trim())
        .map(|&(_, value)| value)
        .ok_or_else(|| RenderError::Gpu(format!("{name}={v:?} is not {what}")))
}

/// The environment variable `name`, None when unset or empty (`STCVAE_GPU_BOUNCES=` in a
/// script that clears a setting means the default, as a shell's unset would; a value that
/// is not Unicode is passed on lossily, so that the range error shows it).
fn env_value(name: &str) -> Option<String> {
    value_of(std::env::var(name))
}

/// [`env_value`]'s rule on what `std::env::var` gave, apart so that tests need not set
/// variables while other tests of the binary start Vulkan (whose loader reads the
/// environment through libc, outside std's lock).
fn value_of(var: Result<String, std::env::VarError>) -> Option<String> {
    match var {
        Ok(v) if v.trim().is_empty() => None,
        Ok(v) => Some(v),
        Err(std::env::VarError::NotPresent) => None,
        Err(std::env::VarError::NotUnicode(v)) => Some(v.to_string_lossy().into_owned()),
    }
}

/// A whole number in 1..=`max` from the variable `name`, or the error that names it, its
/// range and its `unit`.
fn parse_count(name: &str, v: &str, max: u32, unit: &str) -> Result<u32, RenderError> {
    v.trim()
        .parse::<u32>()
        .ok()
        .filter(|n| (1..=max).contains(n))
        .ok_or_else(|| {
            RenderError::Gpu(format!(
                "{name}={v:?} is out of range: allowed 1 to {max} {unit} (unset it for the default)"
            ))
        })
}

/// The most samples an invocation may take in one chunk (a chunk's sample range is u32).
pub(super) const MAX_LANE_SAMPLES: u32 = 65_536;

/// The most bounces a dispatch may be given: lavapipe's loop limit, which every bounce
/// takes at least one iteration of. Hardware GPUs gained < 6 % from 256 to 1024.
const MAX_BOUNCES: u32 = 65_535;

/// Turns of the staged render per submission: the pending count is read back after each
/// submission; turns after the chunk's last path ended dispatch nothing (their queues are
/// empty). `STCVAE_GPU_STAGED_ROUNDS` sets it (1 to [`MAX_STAGED_ROUNDS`]), for measuring
/// what the readbacks cost on hardware.
const STAGED_ROUNDS: u32 = 8;

const MAX_STAGED_ROUNDS: u32 = 4096;

pub(super) fn staged_rounds() -> Result<u32, RenderError> {
    staged_rounds_from(env_value("STCVAE_GPU_STAGED_ROUNDS"))
}

/// [`staged_rounds`] from the variable's value as [`env_value`] reads it.
fn staged_rounds_from(value: Option<String>) -> Result<u32, RenderError> {
    value.map_or(Ok(STAGED_ROUNDS), |v| {
        parse_count(
            "STCVAE_GPU_STAGED_ROUNDS",
            &v,
            MAX_STAGED_ROUNDS,
            "turns of the staged render per submission",
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernel_shape_takes_only_the_offered_values() {
        // SAFETY: no other test of this binary reads these variables.
        let with = |wg: &str, stack: &str| {
            unsafe {
                std::env::set_var("STCVAE_GPU_WORKGROUP", wg);
                std::env::set_var("STCVAE_GPU_STACK", stack);
            }
            let r = kernel_shape();
            unsafe {
                std::env::remove_var("STCVAE_GPU_WORKGROUP");
                std::env::remove_var("STCVAE_GPU_STACK");
            }
            r
        };
        let s = with("128", "private").unwrap();
        assert_eq!((s.workgroup, s.stack), (128, StackMemory::Private));
        // `with` leaves both unset: the defaults.
        assert_eq!(kernel_shape().unwrap(), KernelShape::default());
        assert_eq!(with(" 8 ", "workgroup").unwrap().workgroup, 8);
        // Empty is unset, as for every variable here.
        assert_eq!(with("", " ").unwrap(), KernelShape::default());
        for bad in ["0", "48", "512", "-64", "sixty-four"] {
            let e = with(bad, "workgroup").unwrap_err().to_string();
            assert!(
                e.contains("STCVAE_GPU_WORKGROUP") && e.contains("[8, 16, 32, 64, 128, 256]"),
                "{e}"
            );
        }
        // The shape with one variable set (and unset again after).
        let with_one = |name: &str, v: &str| {
            unsafe { std::env::set_var(name, v) };
            let r = kernel_shape();
            unsafe { std::env::remove_var(name) };
            r
        };
        for (v, on) in [("1", true), ("true", true), ("0", false), ("", false)] {
            let r = with_one("STCVAE_GPU_PROFILE", v);
            assert_eq!(r.unwrap().profile, on, "{v:?}");
        }
        // Empty is the default, also where the default is on.
        for (v, on) in [("", true), (" ", true), ("0", false)] {
            let r = with_one("STCVAE_GPU_STAGED_AHEAD", v);
            assert_eq!(r.unwrap().ahead, on, "{v:?}");
        }
        assert!(KernelShape::default().ahead);
        let e = with_one("STCVAE_GPU_PROFILE", "yes")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("STCVAE_GPU_PROFILE") && e.contains("1 or true"),
            "{e}"
        );
        // Each of `bad` refused, the message naming the variable and its `allowed` range.
        let refused = |name: &str, bad: &[&str], allowed: &str| {
            for b in bad {
                let e = with_one(name, b).unwrap_err().to_string();
                assert!(e.contains(name) && e.contains(allowed), "{e}");
            }
        };
        // The test hook: a pixel index, u32::MAX (its "none") refused.
        for (v, want) in [("7", Some(7)), (" 0 ", Some(0)), ("", None)] {
            let r = with_one("STCVAE_GPU_TEST_UNWRITTEN_PIXEL", v);
            assert_eq!(r.unwrap().unwritten_pixel, want, "{v:?}");
        }
        for bad in ["-1", "4294967295", "x"] {
            let e = with_one("STCVAE_GPU_TEST_UNWRITTEN_PIXEL", bad)
                .unwrap_err()
                .to_string();
            assert!(e.contains("STCVAE_GPU_TEST_UNWRITTEN_PIXEL"), "{e}");
        }
        // The dispatch row's hook: 1 to 65,535 workgroups, unset the most a dimension holds.
        for (v, want) in [("5", 5), (" 1 ", 1), ("65535", 65_535), ("", 65_535)] {
            let r = with_one("STCVAE_GPU_TEST_DISPATCH_ROW", v);
            assert_eq!(r.unwrap().dispatch_row, want, "{v:?}");
        }
        refused(
            "STCVAE_GPU_TEST_DISPATCH_ROW",
            &["0", "65536", "-1", "x"],
            "allowed 1 to 65535",
        );
        // The cut-offs' hook: 0 to 16 dispatches, unset none.
        for (v, want) in [("2", 2), (" 16 ", 16), ("0", 0), ("", 0)] {
            let r = with_one("STCVAE_GPU_TEST_CUT_OFFS", v);
            assert_eq!(r.unwrap().cut_offs, want, "{v:?}");
        }
        refused(
            "STCVAE_GPU_TEST_CUT_OFFS",
            &["17", "-1", "x"],
            "allowed 0 to 16",
        );
        // The band cap's hook: 1 to 2^22 slots (a hardware band's most), unset none.
        for (v, want) in [("1536", Some(1536)), (" 1 ", Some(1)), ("", None)] {
            let r = with_one("STCVAE_GPU_TEST_BAND_SLOTS", v);
            assert_eq!(r.unwrap().band_slots, want, "{v:?}");
        }
        let r = with_one("STCVAE_GPU_TEST_BAND_SLOTS", "4194304");
        assert_eq!(r.unwrap().band_slots, Some(1 << 22));
        refused(
            "STCVAE_GPU_TEST_BAND_SLOTS",
            &["0", "4194305", "-1", "x"],
            "allowed 1 to 4194304",
        );
        let e = with("64", "shared").unwrap_err().to_string();
        assert!(
            e.contains("STCVAE_GPU_STACK") && e.contains("workgroup or private"),
            "{e}"
        );
    }

    #[test]
    fn lane_samples_take_only_counts_in_range() {
        assert_eq!(parse_lane_samples("8").unwrap(), Some(8));
        for bad in ["0", "-1", "65537", "x", ""] {
            let e = parse_lane_samples(bad).unwrap_err().to_string();
            assert!(
                e.contains("STCVAE_GPU_LANE_SAMPLES") && e.contains("1 to 65536"),
                "{e}"
            );
        }
    }

    #[test]
    fn bounce_budget_takes_only_counts_in_range() {
        assert_eq!(parse_bounces("64").unwrap(), 64);
        assert_eq!(parse_bounces(" 1 ").unwrap(), 1);
        assert_eq!(parse_bounces("65535").unwrap(), MAX_BOUNCES);
        for bad in ["0", "-1", "abc", "", "65536", "1e3"] {
            let e = parse_bounces(bad).unwrap_err().to_string();
            assert!(e.contains("allowed 1 to 65535"), "{bad:?}: {e}");
        }
    }

    /// A switch reads every offered spelling as documented: "false" is off like "0", and
    /// "true" on like "1" (the existing test never tries "false").
    #[test]
    fn switches_read_false_as_off() {
        for (v, on) in [("false", false), ("0", false), ("true", true), ("1", true)] {
            let got = parse_switch("STCVAE_GPU_STAGED_AHEAD", v, "w").unwrap();
            assert_eq!(got, on, "{v:?}");
        }
    }

    /// A switch's or a choice's value is read trimmed, as every count here is: env_value
    /// passes a non-blank value on untrimmed, so " 1" or "private " must still be taken.
    #[test]
    fn switch_and_choice_values_are_read_trimmed() {
        assert!(parse_switch("STCVAE_GPU_STAGED", " 1\n", "w").unwrap());
        assert!(!parse_switch("STCVAE_GPU_STAGED", "\tfalse ", "w").unwrap());
        let stack = parse_choice(
            "STCVAE_GPU_STACK",
            " private ",
            &[
                ("workgroup", StackMemory::Workgroup),
                ("private", StackMemory::Private),
            ],
            "a stack memory",
        )
        .unwrap();
        assert_eq!(stack, StackMemory::Private);
    }

    /// A value that is not Unicode is passed on (lossily) so that the range check refuses
    /// it by name, never dropped as if unset (which would render with the default).
    #[cfg(unix)]
    #[test]
    fn a_value_that_is_not_unicode_is_refused_not_ignored() {
        use std::os::unix::ffi::OsStringExt;
        let raw = std::ffi::OsString::from_vec(b"12\xff".to_vec());
        let v = value_of(Err(std::env::VarError::NotUnicode(raw)));
        let v = v.expect("a set, non-blank value that is not Unicode is passed on");
        assert_eq!(v, "12\u{fffd}");
        let e = parse_bounces(&v).unwrap_err().to_string();
        assert!(e.contains("STCVAE_GPU_BOUNCES"), "{e}");
    }

    /// `STCVAE_GPU_STAGED_ROUNDS` takes 1 to MAX_STAGED_ROUNDS (4096) as documented, the
    /// default 8 when unset or blank, and refuses the rest by name.
    #[test]
    fn staged_rounds_take_the_documented_range() {
        let name = "STCVAE_GPU_STAGED_ROUNDS";
        // The variable's value as it would be read, without setting it (see `value_of`).
        let with = |v: &str| staged_rounds_from(value_of(Ok(v.to_string())));
        assert_eq!(staged_rounds_from(None).unwrap(), STAGED_ROUNDS);
        assert_eq!(with("").unwrap(), STAGED_ROUNDS);
        assert_eq!(with("1").unwrap(), 1);
        // 64: above the default 8, inside the documented 1..=4096.
        assert_eq!(with("64").unwrap(), 64);
        assert_eq!(with(" 4096 ").unwrap(), MAX_STAGED_ROUNDS);
        for bad in ["0", "4097", "-1", "x"] {
            let e = with(bad).unwrap_err().to_string();
            assert!(
                e.contains(name) && e.contains("allowed 1 to 4096"),
                "{bad:?}: {e}"
            );
        }
    }
}
