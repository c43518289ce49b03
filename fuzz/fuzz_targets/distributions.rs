//! Arbitrary raw network outputs → every representation; see
//! `guiding_tests::fuzz_checks::distributions`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    guiding_tests::fuzz_checks::distributions(data);
});
