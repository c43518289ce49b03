//! Runtime tests that need no embedded SPIR-V: selection parsing, device
//! enumeration and its error paths, buffers, argument checks.

mod common;

use common::{assert_validation_clean, staging_context};
use guiding_gpu::test_support::is_absent;
use guiding_gpu::*;

/// A context for these tests, which need a device but no SPIR-V.
fn device_context(options: &ContextOptions) -> Option<GpuContext> {
    test_context_with(TestNeeds::Device, options)
}

#[test]
fn shader_module_reports_whether_it_was_built() {
    let m = shader_module();
    if cfg!(feature = "shaders") {
        let words = m.expect("built with --features shaders");
        assert_eq!(words[0], 0x0723_0203, "SPIR-V magic");
    } else {
        let e = m.unwrap_err();
        assert!(matches!(e, GpuError::ShadersNotBuilt), "{e}");
        assert!(e.to_string().contains("--features shaders"), "{e}");
    }
}

#[test]
fn device_selection_parses_and_round_trips() {
    let cases = [
        ("auto", DeviceSelection::Auto),
        ("AUTO", DeviceSelection::Auto),
        (" gpu ", DeviceSelection::Gpu),
        ("cpu", DeviceSelection::Cpu),
        ("0", DeviceSelection::Index(0)),
        ("12", DeviceSelection::Index(12)),
        ("name:llvmpipe", DeviceSelection::Name("llvmpipe".into())),
        (
            "NAME:GeForce RTX",
            DeviceSelection::Name("GeForce RTX".into()),
        ),
    ];
    for (text, want) in cases {
        let got: DeviceSelection = text.parse().unwrap();
        assert_eq!(got, want, "{text}");
        assert_eq!(got.to_string().parse::<DeviceSelection>().unwrap(), got);
    }
    for bad in [
        "",
        "fastest",
        "name:",
        "-1",
        "1.5",
        "99999999999999999999999",
    ] {
        let e = bad.parse::<DeviceSelection>().unwrap_err();
        assert!(matches!(e, GpuError::InvalidSelection { .. }), "{bad}: {e}");
    }
    assert_eq!(DeviceSelection::default(), DeviceSelection::Auto);
}

#[test]
fn enumeration_lists_devices_or_says_why_not() {
    match enumerate_devices() {
        Ok(devices) => {
            for (i, d) in devices.iter().enumerate() {
                assert_eq!(d.index, i);
                assert!(!d.name.is_empty());
                eprintln!("{d} unusable: {:?}", d.unusable_reason());
            }
        }
        Err(e) => assert!(is_absent(&e), "unexpected error: {e}"),
    }
}

#[test]
fn impossible_selections_fail_with_the_device_list() {
    for sel in [
        DeviceSelection::Index(10_000),
        DeviceSelection::Name("no-such-device-xyz".into()),
    ] {
        let e = match GpuContext::new(sel.clone()) {
            Ok(_) => panic!("{sel} matched a device"),
            Err(e) => e,
        };
        let msg = e.to_string();
        match e {
            GpuError::NoMatchingDevice { .. } => {
                assert!(msg.contains(&format!("--device {sel}")), "{msg}");
                if let Ok(devices) = enumerate_devices() {
                    for d in devices {
                        assert!(msg.contains(&d.name), "{msg} lacks {}", d.name);
                    }
                }
            }
            GpuError::NoLoader(_) | GpuError::NoDevice => {
                assert!(msg.contains("mesa-vulkan-drivers"), "{msg}");
            }
            e => panic!("unexpected error for {sel}: {e}"),
        }
    }
}

#[test]
fn device_info_reports_the_limits() {
    let Some(ctx) = device_context(&ContextOptions::default()) else {
        return;
    };
    let info = ctx.device_info();
    assert!(info.api_version >= (1, 2, 0));
    assert!(info.vulkan_memory_model && info.unusable_reason().is_none());
    assert!(
        info.max_storage_buffer_range >= 1 << 27,
        "Vulkan 1.2 minimum is 2^27"
    );
    assert!(info.max_compute_work_group_count[0] >= 65535);
    assert!(info.max_push_constants_size >= 128);
    if info.device_type == DeviceType::Cpu {
        assert!(ctx.mapped_buffers(), "lavapipe has unified memory");
    }
}

fn round_trip(ctx: &GpuContext) {
    let data: Vec<u32> = (0..10_001u32)
        .map(|i| i.wrapping_mul(2_654_435_761))
        .collect();
    let mut b = ctx.buffer_from(&data).unwrap();
    assert_eq!(b.size(), 4 * 10_001);
    assert_eq!(b.len_of::<u32>(), 10_001);
    assert_eq!(b.download::<u32>().unwrap(), data);
    // A partial upload keeps the tail.
    b.upload(&[7u32, 8]).unwrap();
    let got: Vec<u32> = b.download().unwrap();
    assert_eq!(&got[..2], &[7, 8]);
    assert_eq!(&got[2..], &data[2..]);
    let mut head = [0u32; 3];
    b.download_into(&mut head).unwrap();
    assert_eq!(head, [7, 8, data[2]]);
    // Fresh buffers are zeroed, odd sizes work.
    let z = ctx.buffer(7).unwrap();
    assert_eq!(z.download::<u8>().unwrap(), vec![0u8; 7]);
    let empty = ctx.buffer_from::<f32>(&[]).unwrap();
    assert_eq!(empty.download::<f32>().unwrap(), Vec::<f32>::new());
}

#[test]
fn buffers_round_trip() {
    let Some(ctx) = device_context(&ContextOptions::default()) else {
        return;
    };
    round_trip(&ctx);
    assert_validation_clean(&ctx);
}

#[test]
fn buffers_round_trip_through_staging() {
    let Some(ctx) = staging_context(TestNeeds::Device) else {
        return;
    };
    round_trip(&ctx);
    assert_validation_clean(&ctx);
}

#[test]
fn buffer_misuse_is_an_error() {
    let Some(ctx) = device_context(&ContextOptions::default()) else {
        return;
    };
    let limit = ctx.device_info().max_storage_buffer_range;
    let e = ctx.buffer(limit + 1).map(|_| ()).unwrap_err();
    assert!(
        matches!(
            e,
            GpuError::BufferTooLarge {
                limit_name: "maxStorageBufferRange",
                ..
            }
        ),
        "{e}"
    );
    let mut b = ctx.buffer(8).unwrap();
    assert!(matches!(
        b.upload(&[0u32; 3]),
        Err(GpuError::BadArgument(_))
    ));
    assert!(matches!(
        b.download::<[u8; 3]>(),
        Err(GpuError::BadArgument(_))
    ));
    let mut big = [0u32; 3];
    assert!(matches!(
        b.download_into(&mut big),
        Err(GpuError::BadArgument(_))
    ));
    assert_validation_clean(&ctx);
}

#[test]
fn kernel_rejects_what_is_not_spirv() {
    let Some(ctx) = device_context(&ContextOptions::default()) else {
        return;
    };
    for words in [
        &[][..],
        &[1, 2, 3, 4, 5][..],
        &[0x0723_0203, 0x0001_0500, 0, 1, 0, 0x00ff_0001][..],
    ] {
        let e = ctx.kernel(words, "main", 1, 0).map(|_| ()).unwrap_err();
        assert!(matches!(e, GpuError::InvalidSpirv(_)), "{e}");
    }
    // A valid header without entry points.
    let e = ctx
        .kernel(&[0x0723_0203, 0x0001_0500, 0, 1, 0], "main", 1, 0)
        .map(|_| ())
        .unwrap_err();
    assert!(
        e.to_string().contains("no compute entry point \"main\""),
        "{e}"
    );
}

#[test]
fn handles_are_thread_safe_where_documented() {
    fn send_sync<T: Send + Sync>() {}
    fn send<T: Send>() {}
    send_sync::<GpuContext>();
    send_sync::<Kernel>();
    send_sync::<GpuError>();
    send::<GpuBuffer>();
}
