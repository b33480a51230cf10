#![no_main]

use libfuzzer_sys::fuzz_target;
use prognos_core::filter::adaptive_ukf::Adaptation;

fuzz_target!(
    |data: &[u8]| prognos_fuzz::run(data, |f| prognos_fuzz::fuzz::adaptive_ukf(
        f,
        Adaptation::Enhanced
    ))
);
