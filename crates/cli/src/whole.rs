//! Whole-number options. clap's own parsers said only "invalid digit found in string" for
//! -1, 1.5 or 10^30, without the allowed range; these name it whatever was typed.

/// A parser of whole numbers from `lo` to `hi` (inclusive) into `T`, which must hold `hi`.
pub fn whole<T>(lo: u64, hi: u64) -> impl Fn(&str) -> Result<T, String> + Clone + Send + Sync
where
    T: TryFrom<u64>,
{
    move |s: &str| {
        let range = scatter_sim::ranges::whole_range(lo, hi);
        let v: u64 = s
            .trim()
            .parse()
            .map_err(|_| format!("expected a whole number in {range}"))?;
        if !(lo..=hi).contains(&v) {
            return Err(format!("{v} is out of range: allowed {range}"));
        }
        T::try_from(v).map_err(|_| format!("allowed {range}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_bad_value_names_the_range() {
        let p = whole::<u32>(2, 4096);
        assert_eq!(p("16"), Ok(16));
        assert_eq!(p(" 4096 "), Ok(4096));
        for bad in ["-1", "1.5", "1e3", "", "x", "99999999999999999999999"] {
            assert_eq!(
                p(bad),
                Err("expected a whole number in [2, 4096]".to_string()),
                "{bad}"
            );
        }
        assert_eq!(p("1"), Err("1 is out of range: allowed [2, 4096]".into()));
        assert_eq!(
            p("5000"),
            Err("5000 is out of range: allowed [2, 4096]".into())
        );
        let seeds = whole::<u64>(0, u64::MAX);
        assert_eq!(seeds("18446744073709551615"), Ok(u64::MAX));
        assert_eq!(
            seeds("-3"),
            Err("expected a whole number in [0, 2^64)".to_string())
        );
        assert_eq!(
            whole::<u32>(1, u32::MAX.into())("0"),
            Err("0 is out of range: allowed [1, 2^32)".to_string())
        );
    }
}
