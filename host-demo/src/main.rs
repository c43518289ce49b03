//! `host-demo render SCENE --integrator pt|pt-nee|guided (--spp N | --time SECONDS) --out FILE.exr
//! [--stats FILE.json] ...` and `host-demo compare IMAGE.exr REFERENCE.exr`.
//!
//! Guided example (the README's main command, about 20 s on 2 cores):
//! `host-demo render builtin:door --integrator guided --guide npm --target radiance --spp 32 --out door-guided.exr`

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
