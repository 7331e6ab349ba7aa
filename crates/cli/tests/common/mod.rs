//! Helpers shared by the CLI tests that run the binary in a scratch directory.

use std::path::Path;
use std::process::{Command, Output};

/// Runs `stcvae args…` with `dir` as the current directory.
pub fn stcvae(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_stcvae"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run stcvae")
}

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}
