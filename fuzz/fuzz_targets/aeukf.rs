#![no_main]

use prognos_core::filter::adaptive_ukf::Adaptation;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| prognos_fuzz::run(data, |f| prognos_fuzz::fuzz::adaptive_ukf(f, Adaptation::Enhanced)));
