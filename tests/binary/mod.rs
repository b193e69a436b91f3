//! Running the `eikon` binary from the end-to-end tests (`cli`, `vdb`).
#![allow(dead_code)] // each test binary uses some of these helpers

use std::process::{Command, Output};

/// Run `eikon` with `args`.
pub fn eikon(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_eikon"))
        .args(args)
        .output()
        .expect("run eikon")
}

/// Run, and require success (showing stderr if not).
pub fn eikon_ok(args: &[&str]) -> Output {
    let out = eikon(args);
    assert!(
        out.status.success(),
        "eikon {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Run with bad input: must fail with exit code 1, print `error:` with every
/// expected fragment, and never panic.
pub fn expect_error(args: &[&str], fragments: &[&str]) -> String {
    let out = eikon(args);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "args {args:?}\nstderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    assert!(err.starts_with("error: "), "{err}");
    for f in fragments {
        assert!(err.contains(f), "missing `{f}` in: {err}");
    }
    err
}

/// [`expect_error`] for commands that print what they will build on stderr
/// before failing (the grid flags): the error is the first line that starts
/// with `error: `, and what follows it; returns it.
pub fn expect_error_after_notes(args: &[&str], fragments: &[&str]) -> String {
    let out = eikon(args);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "args {args:?}\nstderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    let at = err
        .find("error: ")
        .unwrap_or_else(|| panic!("no error in: {err}"));
    assert!(at == 0 || err[..at].ends_with('\n'), "{err}");
    let error = err[at..].to_string();
    for f in fragments {
        assert!(error.contains(f), "missing `{f}` in: {error}");
    }
    error
}
