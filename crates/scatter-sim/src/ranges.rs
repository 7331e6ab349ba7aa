//! The parameter ranges the project accepts, in one place.
//!
//! τ is the optical radius σ_t·r of the sphere, g the Henyey–Greenstein parameter and
//! φ the single-scattering albedo. The walk cost grows like τ², so τ is capped; |g| is
//! kept away from 1 where HG degenerates to a delta (the authors clamp to ±0.999).

use thiserror::Error;

/// Largest |g| anywhere in the project (the authors' clamp).
pub const G_MAX: f64 = 0.999;
/// Largest optical radius the simulator accepts (a walk at τ = 1000 takes ~5·10⁵ events).
pub const TAU_LIMIT: f64 = 1000.0;
/// Upper end of the authors' training distribution τ = 300·u³.
pub const AUTHORS_TAU_MAX: f64 = 300.0;
/// [`TAU_LIMIT`]'s and [`G_MAX`]'s ranges as messages and `--help` texts write them
/// (tested equal to the numbers, and the CLI's help against these).
pub const TAU_RANGE: &str = "[0, 1000]";
pub const G_RANGE: &str = "[-0.999, 0.999]";

/// A value for a range message: [`Short`]'s digits.
pub fn num<T>(v: T) -> String
where
    T: Copy + Into<f64> + std::fmt::Display + std::fmt::LowerExp,
{
    Short(v).to_string()
}

/// A path as messages show it: [`printable`] of its display form.
pub fn printable_path(p: &std::path::Path) -> String {
    printable(&p.display().to_string())
}

/// `s` with control characters escaped (`\n`, `\u{1b}`): every message is one line, and a
/// file name, tag or config text taken from a damaged or hostile file may hold newlines
/// and terminal escapes, which must not reach the terminal raw (a mesh path with an ESC
/// sequence cleared the screen).
pub fn printable(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

/// A number written short and exact, for messages and CSV rows alike: the shortest digits
/// that read back to the same value in its own type (an f32 as its shortest f32 digits),
/// in scientific notation when plain digits would run long (1e38 rather than 39 digits,
/// 1e-7 rather than 0.0000001; Rust's `{}` never uses an exponent, and an albedo of 1e-300
/// took 302 characters in a CSV row). Zero is written 0 whatever its sign (`--tau -0` wrote
/// -0); every other value reads back bit for bit.
pub struct Short<T>(pub T);

impl<T> std::fmt::Display for Short<T>
where
    T: Copy + Into<f64> + std::fmt::Display + std::fmt::LowerExp,
{
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let x: f64 = self.0.into();
        if x == 0.0 {
            f.write_str("0")
        } else if x.is_finite() && !(1e-4..1e6).contains(&x.abs()) {
            write!(f, "{:e}", self.0)
        } else {
            write!(f, "{}", self.0)
        }
    }
}

/// A parameter outside its allowed range; the message names the field and the range.
#[derive(Debug, Error, Clone, PartialEq)]
#[error("{field} = {} is out of range: allowed {allowed}", num(*value))]
pub struct RangeError {
    pub field: String,
    pub value: f64,
    pub allowed: &'static str,
}

fn check(field: &str, value: f64, ok: bool, allowed: &'static str) -> Result<(), RangeError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(RangeError {
            field: field.to_string(),
            value,
            allowed,
        })
    }
}

/// τ ∈ [0, TAU_LIMIT].
pub fn check_tau(field: &str, tau: f64) -> Result<(), RangeError> {
    check(field, tau, (0.0..=TAU_LIMIT).contains(&tau), TAU_RANGE)
}

/// g ∈ [−G_MAX, G_MAX].
pub fn check_g(field: &str, g: f64) -> Result<(), RangeError> {
    check(field, g, (-G_MAX..=G_MAX).contains(&g), G_RANGE)
}

/// φ ∈ [0, 1].
pub fn check_albedo(field: &str, albedo: f64) -> Result<(), RangeError> {
    check(field, albedo, (0.0..=1.0).contains(&albedo), "[0, 1]")
}

/// `[lo, hi]` of whole numbers, with 2^64, 2^32 and larger powers of two (the trainer's
/// 2^40 steps) written as such rather than in up to twenty digits: the one wording of the
/// CLI's options and the scene's, experiments' and configs' fields.
pub fn whole_range(lo: u64, hi: u64) -> String {
    match hi {
        u64::MAX => format!("[{lo}, 2^64)"),
        h if h == u64::from(u32::MAX) => format!("[{lo}, 2^32)"),
        h if h.is_power_of_two() && h > u64::from(u32::MAX) => {
            format!("[{lo}, 2^{}]", h.trailing_zeros())
        }
        h => format!("[{lo}, {h}]"),
    }
}

/// A serde visitor for a config file's whole-number field of range [lo, hi]: a value the
/// type `T` cannot hold (negative, fractional, beyond it) is refused with the field's own
/// range ("expected a whole number in [8, 4096]"), not the type's ("[0, 4294967295]"). A
/// value `T` holds is returned even out of range, for the config's validation, which
/// names the field and says why the range is what it is.
pub struct WholeIn<T> {
    pub lo: u64,
    pub hi: u64,
    pub of: std::marker::PhantomData<T>,
}

impl<T> WholeIn<T> {
    pub fn new(lo: u64, hi: u64) -> Self {
        Self {
            lo,
            hi,
            of: std::marker::PhantomData,
        }
    }
}

impl<T: TryFrom<u64>> serde::de::Visitor<'_> for WholeIn<T> {
    type Value = T;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "a whole number in {}", whole_range(self.lo, self.hi))
    }
    fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<T, E> {
        T::try_from(v).map_err(|_| E::invalid_value(serde::de::Unexpected::Unsigned(v), &self))
    }
    fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<T, E> {
        u64::try_from(v)
            .ok()
            .and_then(|u| T::try_from(u).ok())
            .ok_or_else(|| E::invalid_value(serde::de::Unexpected::Signed(v), &self))
    }
    /// Refused as serde would, but written short: serde writes the float in full
    /// (`width = 1e308` gave 309 digits); Debug keeps `128.0` as written and gives `1e308`.
    fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<T, E> {
        let shown = format!("floating point `{v:?}`");
        Err(E::invalid_type(serde::de::Unexpected::Other(&shown), &self))
    }
}

/// One element of a list read by [`WholeListIn`].
impl<'de, T: TryFrom<u64>> serde::de::DeserializeSeed<'de> for WholeIn<T> {
    type Value = T;
    fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<T, D::Error> {
        d.deserialize_u64(self)
    }
}

/// A config file's list of whole numbers, each of range [lo, hi]: `hidden = [16, -1]`
/// said "expected a whole number, at least 0" (serde's usize) where 0 is refused too.
pub struct WholeListIn<T>(pub WholeIn<T>);

impl<'de, T: TryFrom<u64>> serde::de::Visitor<'de> for WholeListIn<T> {
    type Value = Vec<T>;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(
            f,
            "a list of whole numbers in {}",
            whole_range(self.0.lo, self.0.hi)
        )
    }
    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<T>, A::Error> {
        let mut v = Vec::new();
        while let Some(x) = seq.next_element_seed(WholeIn::<T>::new(self.0.lo, self.0.hi))? {
            v.push(x);
        }
        Ok(v)
    }
}

/// Reads a whole number of range [lo, hi] with [`WholeIn`] (for `deserialize_with`).
pub fn whole_in<'de, D: serde::Deserializer<'de>, T: TryFrom<u64>>(
    d: D,
    lo: u64,
    hi: u64,
) -> Result<T, D::Error> {
    d.deserialize_u64(WholeIn::<T>::new(lo, hi))
}

/// Reads a list of whole numbers of range [lo, hi] with [`WholeListIn`].
pub fn whole_list_in<'de, D: serde::Deserializer<'de>, T: TryFrom<u64>>(
    d: D,
    lo: u64,
    hi: u64,
) -> Result<Vec<T>, D::Error> {
    d.deserialize_seq(WholeListIn(WholeIn::<T>::new(lo, hi)))
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_range_texts_are_the_limits() {
        assert_eq!(super::TAU_RANGE, format!("[0, {}]", super::TAU_LIMIT));
        assert_eq!(super::G_RANGE, format!("[-{0}, {0}]", super::G_MAX));
    }
}
