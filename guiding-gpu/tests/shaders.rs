//! The embedded rust-gpu module on a real device: the exact
//! `add_index_kernel` on 1-D and 2-D grids and in chained batches,
//! `exp_kernel` against `guiding_core::math::exp` on the CPU, argument
//! checks, and `spirv-val` of the module.
#![cfg(feature = "shaders")]

mod common;

use common::{assert_validation_clean, staging_context};
use guiding_gpu::*;

/// Distance in units in the last place between two finite-or-infinite
/// floats of the same sign; 0 for two NaNs; `u32::MAX` otherwise.
fn ulps(a: f32, b: f32) -> u32 {
    if a.is_nan() || b.is_nan() {
        return if a.is_nan() && b.is_nan() {
            0
        } else {
            u32::MAX
        };
    }
    if a == b {
        return 0; // includes +0 == -0
    }
    if a.is_sign_negative() != b.is_sign_negative() {
        return u32::MAX;
    }
    a.to_bits().abs_diff(b.to_bits())
}

/// Runs `kernel` (bindings `in`, `out`, push constant `n = input.len()`)
/// over `input` padded with `slack` elements `pad`, into an output of
/// `input.len() + slack` elements `sentinel`, in a timed batch; returns the
/// whole output and the report.
fn run_padded<T: bytemuck::Pod>(
    ctx: &GpuContext,
    kernel: &Kernel,
    input: &[T],
    slack: usize,
    (pad, sentinel): (T, T),
) -> (Vec<T>, BatchReport) {
    let mut padded = input.to_vec();
    padded.resize(input.len() + slack, pad);
    let a = ctx.buffer_from(&padded).unwrap();
    let b = ctx
        .buffer_from(&vec![sentinel; input.len() + slack])
        .unwrap();
    let n = input.len() as u32;
    let mut batch = ctx.timed_batch().unwrap();
    batch
        .dispatch(kernel, &[&a, &b], bytemuck::bytes_of(&n), n)
        .unwrap();
    let report = batch.submit_and_wait().unwrap();
    (b.download().unwrap(), report)
}

/// Runs `exp_kernel` over `input` (`n = input.len()`) into a buffer with
/// `slack` extra sentinel elements; returns the whole output and the report.
fn gpu_exp(ctx: &GpuContext, input: &[f32], slack: usize) -> (Vec<f32>, BatchReport) {
    let kernel = ctx.embedded_kernel("exp_kernel", 2, 4).unwrap();
    assert_eq!(kernel.workgroup_size(), 64);
    run_padded(ctx, &kernel, input, slack, (0.5, -1.0))
}

/// Compares with the CPU; returns (exact matches, max ulps).
fn compare(input: &[f32], out: &[f32]) -> (usize, u32) {
    let mut exact = 0;
    let mut worst = 0;
    for (i, (&x, &y)) in input.iter().zip(out).enumerate() {
        let want = guiding_core::math::exp(x);
        let d = ulps(want, y);
        assert!(
            d <= 1,
            "exp({x:e}) [{i}]: GPU {y:e}, CPU {want:e} ({d} ulp)"
        );
        exact += usize::from(want.to_bits() == y.to_bits() || d == 0);
        worst = worst.max(d);
    }
    (exact, worst)
}

/// Runs `add_index_kernel` (`out[i] = in[i] + i` for `i < n`) with `slack`
/// extra sentinel elements in both buffers, in a timed batch, and checks
/// the output exactly (the sentinels past `n` untouched); returns the report.
fn run_add_index(ctx: &GpuContext, input: &[u32], slack: usize) -> BatchReport {
    let kernel = ctx.embedded_kernel("add_index_kernel", 2, 4).unwrap();
    let (out, report) = run_padded(ctx, &kernel, input, slack, (7, u32::MAX));
    for (i, (&x, &y)) in input.iter().zip(&out).enumerate() {
        assert_eq!(y, x.wrapping_add(i as u32), "element {i}");
    }
    assert!(
        out[input.len()..].iter().all(|&v| v == u32::MAX),
        "invocations past n wrote into the output"
    );
    report
}

#[test]
fn exp_kernel_matches_the_cpu_on_a_million_inputs() {
    let Some(ctx) = test_context() else { return };
    let n = 1_000_000usize;
    let mut input: Vec<f32> = (0..n)
        .map(|i| -104.0 + 208.0 * i as f32 / n as f32)
        .collect();
    let specials = [
        0.0,
        -0.0,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        88.722_83,
        88.73,
        -87.336_55,
        -87.34,
        1e-40,
        -1e-40,
        f32::MAX,
        f32::MIN,
        f32::EPSILON,
    ];
    input[..specials.len()].copy_from_slice(&specials);
    let (out, report) = gpu_exp(&ctx, &input, 0);
    let (exact, worst) = compare(&input, &out);
    eprintln!(
        "1e6 exp: {exact} bit-exact, max {worst} ulp, GPU time {:?} ns",
        report.gpu_time_ns
    );
    assert_eq!(report.dispatches, 1);
    assert_validation_clean(&ctx);
}

#[test]
fn a_1d_grid_covers_a_million_invocations_and_reports_gpu_time() {
    let Some(ctx) = test_context() else { return };
    let input: Vec<u32> = (0..1_000_000u32)
        .map(|i| i.wrapping_mul(2_654_435_761))
        .collect();
    let report = run_add_index(&ctx, &input, 64);
    assert_eq!(report.dispatches, 1);
    eprintln!("1e6 add_index: GPU time {:?} ns", report.gpu_time_ns);
    if ctx.device_info().timestamps {
        assert!(report.gpu_time_ns.is_some_and(|t| t > 0.0), "{report:?}");
    }
    assert_validation_clean(&ctx);
}

#[test]
fn a_2d_grid_covers_every_invocation_once_and_stops_at_n() {
    let Some(ctx) = test_context() else { return };
    let limits = ctx.device_info().max_compute_work_group_count;
    // One workgroup-row more than the 1-D limit allows, plus a ragged tail.
    let n = limits[0] as usize * 64 + 17;
    let grid = workgroup_grid(n as u32, 64, limits).unwrap();
    assert_eq!(grid, [limits[0], 2, 1]);
    let input: Vec<u32> = (0..n as u32).map(|i| i ^ 0x5555_5555).collect();
    run_add_index(&ctx, &input, 100);
    assert_validation_clean(&ctx);
}

#[test]
fn a_batch_chains_dispatches_through_barriers() {
    let Some(ctx) = test_context() else { return };
    let kernel = ctx.embedded_kernel("add_index_kernel", 2, 4).unwrap();
    let n = 100_000u32;
    let input: Vec<u32> = (0..n).map(|i| i.wrapping_mul(40_503)).collect();
    let a = ctx.buffer_from(&input).unwrap();
    let b = ctx.buffer(4 * u64::from(n)).unwrap();
    let c = ctx.buffer(4 * u64::from(n)).unwrap();
    let push = bytemuck::bytes_of(&n);
    let mut batch = ctx.batch().unwrap();
    batch.dispatch(&kernel, &[&a, &b], push, n).unwrap();
    batch.barrier();
    batch.dispatch(&kernel, &[&b, &c], push, n).unwrap();
    batch.barrier();
    batch.dispatch(&kernel, &[&c, &b], push, n).unwrap();
    batch.dispatch(&kernel, &[&a, &b], push, 0).unwrap(); // records nothing
    assert_eq!(batch.len(), 3);
    let report = batch.submit_and_wait().unwrap();
    assert_eq!(report.dispatches, 3);
    assert_eq!(report.gpu_time_ns, None, "untimed batch");
    // b = a + i, c = a + 2i, then b = c + i = a + 3i.
    let c_got: Vec<u32> = c.download().unwrap();
    let b_got: Vec<u32> = b.download().unwrap();
    for i in 0..n as usize {
        let k = i as u32;
        assert_eq!(c_got[i], input[i].wrapping_add(2 * k), "c[{i}]");
        assert_eq!(b_got[i], input[i].wrapping_add(3 * k), "b[{i}]");
    }
    // The recorder is reused by the next batch.
    let again = ctx.run(&kernel, &[&a, &c], push, n).unwrap();
    assert_eq!(again.dispatches, 1);
    let c_again: Vec<u32> = c.download().unwrap();
    for i in 0..n as usize {
        assert_eq!(c_again[i], input[i].wrapping_add(i as u32), "c[{i}]");
    }
    assert_validation_clean(&ctx);
}

#[test]
fn staging_path_runs_kernels_too() {
    let Some(ctx) = staging_context(TestNeeds::Kernels) else {
        return;
    };
    let input: Vec<u32> = (0..10_000u32).map(|i| i * 3).collect();
    run_add_index(&ctx, &input, 3);
    assert_validation_clean(&ctx);
}

#[test]
fn kernel_arguments_are_checked() {
    let Some(ctx) = test_context() else { return };
    let bad = |r: Result<Kernel, GpuError>| match r {
        Ok(_) => panic!("accepted"),
        Err(e) => e,
    };
    // The module binds 0 and 1 and reads a push constant.
    let e = bad(ctx.embedded_kernel("exp_kernel", 1, 4));
    assert!(
        matches!(e, GpuError::BadArgument(_)) && e.to_string().contains("binding 1"),
        "{e}"
    );
    let e = bad(ctx.embedded_kernel("exp_kernel", 2, 0));
    assert!(matches!(e, GpuError::BadArgument(_)), "{e}");
    let e = bad(ctx.embedded_kernel("exp_kernel", 2, 6));
    assert!(matches!(e, GpuError::BadArgument(_)), "{e}");
    let e = bad(ctx.embedded_kernel("no_such_kernel", 2, 4));
    assert!(
        e.to_string().contains("exp_kernel"),
        "lists the entry points: {e}"
    );

    let kernel = ctx.embedded_kernel("exp_kernel", 2, 4).unwrap();
    let a = ctx.buffer(64).unwrap();
    let n = 16u32;
    let push = bytemuck::bytes_of(&n);
    // A buffer of another context (declared before the batch that borrows it).
    let other = GpuContext::new(DeviceSelection::Auto).unwrap();
    let foreign = other.buffer(64).unwrap();
    let mut batch = ctx.batch().unwrap();
    let e = batch.dispatch(&kernel, &[&a], push, n).unwrap_err();
    assert!(
        e.to_string().contains("takes 2 storage buffers, 1 given"),
        "{e}"
    );
    let e = batch.dispatch(&kernel, &[&a, &a], &[0; 8], n).unwrap_err();
    assert!(
        e.to_string().contains("4 bytes of push constants, 8 given"),
        "{e}"
    );
    let e = batch
        .dispatch(&kernel, &[&a, &a], push, u32::MAX)
        .unwrap_err();
    assert!(matches!(e, GpuError::BadArgument(_)), "{e}");
    let e = batch
        .dispatch(&kernel, &[&a, &foreign], push, n)
        .unwrap_err();
    assert!(e.to_string().contains("another GpuContext"), "{e}");
    assert!(batch.is_empty());
    drop(batch);
    assert_validation_clean(&ctx);
}

#[test]
fn embedded_module_passes_spirv_val() {
    let words = shader_module().unwrap();
    let path = std::env::temp_dir().join(format!("guiding-shaders-{}.spv", std::process::id()));
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    std::fs::write(&path, bytes).unwrap();
    let out = std::process::Command::new("spirv-val")
        .args(["--target-env", "vulkan1.2"])
        .arg(&path)
        .output();
    let _ = std::fs::remove_file(&path);
    match out {
        Err(e) => {
            eprintln!("NOTE: spirv-val not run ({e}); install spirv-tools to check the module")
        }
        Ok(out) => assert!(
            out.status.success(),
            "spirv-val rejected the module:\n{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    }
}
