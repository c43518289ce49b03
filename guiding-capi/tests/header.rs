//! The committed `include/guiding.h` is exactly what cbindgen generates from
//! the current sources and `cbindgen.toml`.

use guiding::ModelSize;
use std::path::Path;

const REGENERATE: &str = "GUIDING_UPDATE_HEADER=1 cargo test -p guiding-capi --test header";

/// The `PG_SIZE_*` `#define`s, one per [`ModelSize`] (the Rust constants are
/// generated from the size table by a macro, which cbindgen does not expand).
fn size_defines() -> String {
    let mut out =
        String::from("\n/* Model sizes (PgModelSize), one per row of the size table. */\n");
    for size in ModelSize::ALL {
        let name = size.name().to_uppercase();
        let doc = size.description();
        out += &format!(
            "\n/**\n * {doc}\n */\n#define PG_SIZE_{name} {}\n",
            size as u32
        );
    }
    out.truncate(out.trim_end().len());
    out
}

fn generate(dir: &Path) -> Vec<u8> {
    let mut config = cbindgen::Config::from_file(dir.join("cbindgen.toml"))
        .unwrap_or_else(|e| panic!("cbindgen.toml: {e}"));
    config.after_includes = Some(size_defines());
    let bindings = cbindgen::Builder::new()
        .with_config(config)
        .with_src(dir.join("src/lib.rs"))
        .generate()
        .unwrap_or_else(|e| panic!("cbindgen failed: {e}"));
    let mut out = Vec::new();
    bindings.write(&mut out);
    out
}

#[test]
fn committed_header_matches_cbindgen_output() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let generated = generate(dir);
    let path = dir.join("include/guiding.h");
    if std::env::var_os("GUIDING_UPDATE_HEADER").is_some() {
        std::fs::write(&path, &generated).unwrap();
        println!("wrote {}", path.display());
        return;
    }
    let committed = std::fs::read(&path).unwrap_or_default();
    if committed != generated {
        let (c, g) = (
            String::from_utf8_lossy(&committed),
            String::from_utf8_lossy(&generated),
        );
        let first = c
            .lines()
            .zip(g.lines())
            .position(|(a, b)| a != b)
            .unwrap_or(c.lines().count().min(g.lines().count()));
        panic!(
            "{} is out of date (first difference at line {}):\n  committed: {:?}\n  generated: {:?}\nRegenerate it with\n  {REGENERATE}\nand commit the result.",
            path.display(),
            first + 1,
            c.lines().nth(first).unwrap_or("<end of file>"),
            g.lines().nth(first).unwrap_or("<end of file>"),
        );
    }
}
