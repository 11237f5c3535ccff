#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| placedb_fuzz::readers::ros1(data));
