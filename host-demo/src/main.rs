//! Placeholder binary. The wavefront path tracer is not implemented yet.

fn main() {
    eprintln!("host-demo: the path tracer is not implemented yet (see the project issues)");
    std::process::exit(2);
}
