//! Arbitrary call sequences on the C ABI (`guiding-capi`); see
//! `guiding_tests::fuzz_checks::c_api`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    guiding_tests::fuzz_checks::c_api(data);
});
