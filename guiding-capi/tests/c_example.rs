//! The C side, with the system C compiler: `include/guiding.h` compiles alone
//! as strict C99, and `examples/toy_renderer.c` compiles against the
//! staticlib cargo built, runs, and passes its own checks (pdf consistency,
//! an unbiased guided estimator with less than half the variance of uniform
//! sampling, the same at scattering points in a medium with the phase-lobe
//! product, error paths, save/load), and fails its medium check when its MIS
//! density skips the product (the negative control).
#![cfg(unix)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const CFLAGS: [&str; 5] = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"];
const LIB: &str = "libguiding_capi.a";

fn crate_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn cc() -> String {
    std::env::var("CC").unwrap_or_else(|_| "cc".to_owned())
}

/// Runs `cmd` and fails the test (with its output) unless it succeeds.
fn check(cmd: &mut Command) -> Output {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e} (a C compiler `cc` is required)"));
    assert!(
        out.status.success(),
        "{cmd:?} failed ({}):\n{}{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// The staticlib of this build: cargo writes it next to the test
/// executable (`target/<profile>/deps`) when it builds the library for the
/// tests; `cargo build` puts it in `target/<profile>`. If neither exists,
/// build it with the same profile.
fn staticlib() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let deps = exe.parent().unwrap();
    let profile_dir = deps.parent().unwrap();
    for dir in [deps, profile_dir] {
        let lib = dir.join(LIB);
        if lib.is_file() {
            return lib;
        }
    }
    let profile = match profile_dir.file_name().and_then(|n| n.to_str()) {
        Some("debug") => "dev".to_owned(),
        Some(name) => name.to_owned(),
        None => panic!("cannot tell the profile from {}", exe.display()),
    };
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".to_owned());
    let target_dir = profile_dir.parent().unwrap();
    check(
        Command::new(cargo)
            .args([
                "build",
                "-p",
                "guiding-capi",
                "--lib",
                "--profile",
                &profile,
            ])
            .arg("--target-dir")
            .arg(target_dir)
            .current_dir(crate_dir()),
    );
    let lib = profile_dir.join(LIB);
    assert!(
        lib.is_file(),
        "cargo build did not produce {}",
        lib.display()
    );
    lib
}

#[test]
fn header_compiles_alone_as_c99() {
    check(
        Command::new(cc())
            .args(CFLAGS)
            .args(["-fsyntax-only", "-x", "c"])
            .arg(crate_dir().join("include/guiding.h")),
    );
}

#[test]
fn toy_renderer_builds_runs_and_passes_its_checks() {
    let tmp = PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    let exe = tmp.join(format!("toy_renderer-{}", std::process::id()));
    check(
        Command::new(cc())
            .args(CFLAGS)
            .arg("-I")
            .arg(crate_dir().join("include"))
            .arg(crate_dir().join("examples/toy_renderer.c"))
            .arg(staticlib())
            .args(["-lpthread", "-ldl", "-lm", "-o"])
            .arg(&exe),
    );
    // NPM (mixture distributions decoded once per query) and DF-L (the
    // network is evaluated per sample / pdf call through the field), run
    // side by side.
    let children: Vec<_> = ["npm", "df_linear"]
        .into_iter()
        .map(|rep| {
            let scratch = tmp.join(format!("toy-{rep}-{}.guide", std::process::id()));
            let child = Command::new(&exe)
                .arg(&scratch)
                .arg(rep)
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap_or_else(|e| panic!("cannot run {}: {e}", exe.display()));
            (rep, child)
        })
        .collect();
    let mut failed = Vec::new();
    for (rep, child) in children {
        let out = child.wait_with_output().unwrap();
        println!("--- toy_renderer {rep} ({}):", out.status);
        println!("{}", String::from_utf8_lossy(&out.stdout));
        eprint!("{}", String::from_utf8_lossy(&out.stderr));
        if !out.status.success() {
            failed.push(rep);
        }
    }
    // The negative control of check (e): samples of the product, densities of the bare
    // guide. The estimate is biased and the check says so.
    let scratch = tmp.join(format!("toy-defect-{}.guide", std::process::id()));
    let out = Command::new(&exe)
        .arg(&scratch)
        .args(["npm", "spp", "defect-medium-pdf"])
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", exe.display()));
    let _ = std::fs::remove_file(&exe);
    let _ = std::fs::remove_file(&scratch);
    assert!(failed.is_empty(), "toy_renderer failed for {failed:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("--- defect-medium-pdf ({}):\n{stderr}", out.status);
    assert!(
        !out.status.success() && stderr.contains("medium estimate"),
        "the medium check missed the sample / pdf mismatch:\n{}{stderr}",
        String::from_utf8_lossy(&out.stdout)
    );
}
