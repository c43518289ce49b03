//! Single lobes with parameters at and beyond the edges of their domains; see
//! `guiding_tests::fuzz_checks::lobes_extreme`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    guiding_tests::fuzz_checks::lobes_extreme(data);
});
