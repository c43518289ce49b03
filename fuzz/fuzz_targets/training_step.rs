//! Arbitrary training batches → the CPU runtime of every small model; see
//! `guiding_tests::fuzz_checks::training_step`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = guiding_tests::fuzz_checks::training_step(data);
});
