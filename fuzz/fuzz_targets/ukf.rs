#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| prognos_fuzz::run(data, prognos_fuzz::fuzz::ukf));
