//! Arbitrary bytes → the Mitsuba XML and OBJ loaders; see
//! `guiding_tests::fuzz_checks::scene_parser`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    guiding_tests::fuzz_checks::scene_parser(data);
});
