//! Panics in code this project does not own, caught and turned into errors.
//!
//! Some libraries panic on input they should refuse: wgpu's poll on a lost device, burn's
//! record loader on a checkpoint whose tensors have another type or shape. The default
//! hook printed "thread 'main' panicked at …" and a backtrace note before (or instead of)
//! the one-line error the caller gives; [`quietly`] catches such a panic without it.

use std::any::Any;

std::thread_local! {
    /// Set while this thread runs [`quietly`]'s closure.
    static QUIET: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `f`, catching a panic as an `Err` without the panic's message. A hook installed
/// once passes every other panic (other threads', and this thread's outside `f`) to the
/// hook it replaced.
pub fn quietly<T>(f: impl FnOnce() -> T) -> std::thread::Result<T> {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !QUIET.with(|q| q.get()) {
                previous(info);
            }
        }));
    });
    let was = QUIET.with(|q| q.replace(true));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    QUIET.with(|q| q.set(was));
    result
}

/// Most characters of a panic's message [`panic_text`] keeps: burn's tensor errors list
/// every reason at length (~500 characters for two mismatched shapes).
pub const MAX_PANIC_TEXT: usize = 240;

/// A caught panic's message on one line, cut at [`MAX_PANIC_TEXT`] characters (a panic's
/// payload is its formatted message, a `String` or a `&str`; anything else says only that
/// it panicked).
pub fn panic_text(payload: &(dyn Any + Send)) -> String {
    let text = payload
        .downcast_ref::<String>()
        .map(String::as_str)
        .or_else(|| payload.downcast_ref::<&str>().copied())
        .unwrap_or("a panic without a message");
    let line = text.split_whitespace().collect::<Vec<_>>().join(" ");
    let cut = match line.char_indices().nth(MAX_PANIC_TEXT) {
        Some((at, _)) => format!("{}…", &line[..at]),
        None => line,
    };
    crate::ranges::printable(&cut)
}

#[cfg(test)]
mod tests {
    use super::{QUIET, panic_text, quietly};

    /// A panic inside `quietly` comes back as an error with its message, the value of a
    /// closure that returns does too, and a panic after it is a panic again: the flag is
    /// cleared whichever way the closure ended, and a nested call leaves it set for the
    /// outer one.
    #[test]
    fn quietly_catches_a_panic_and_then_lets_panics_through() {
        let e = quietly(|| panic!("Parent device {}\nis lost", "x")).unwrap_err();
        assert_eq!(panic_text(&*e), "Parent device x is lost");
        assert_eq!(
            panic_text(&*quietly(|| panic!("plain")).unwrap_err()),
            "plain"
        );
        let long = panic_text(&*quietly(|| panic!("{}", "é".repeat(1000))).unwrap_err());
        assert_eq!(long, format!("{}…", "é".repeat(super::MAX_PANIC_TEXT)));
        assert!(!QUIET.with(|q| q.get()));
        assert_eq!(quietly(|| 7).ok(), Some(7));
        assert!(!QUIET.with(|q| q.get()));
        quietly(|| {
            assert!(quietly(|| panic!("inner")).is_err());
            assert!(QUIET.with(|q| q.get()));
        })
        .unwrap();
        assert!(!QUIET.with(|q| q.get()));
        assert!(std::panic::catch_unwind(|| panic!("a real bug")).is_err());
    }
}
