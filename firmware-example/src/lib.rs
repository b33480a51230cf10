//! Support of the prognos firmware example: the scenarios (shared with the host reference
//! run), simulated sensor front-ends behind `embedded-hal` I2C and their drivers, and the
//! measurement glue (SysTick instruction counts, painted-stack high-water mark, semihosting
//! exit). The two binaries in `src/bin/` run `pipeline::ReactionWheel` and
//! `pipeline::Scooter` on them.
#![no_std]
#![deny(unsafe_code)]

#[cfg(all(feature = "defmt", feature = "plain"))]
compile_error!(
    "choose one log format: default (defmt) or `--no-default-features --features plain`"
);
#[cfg(not(any(feature = "defmt", feature = "plain")))]
compile_error!("enable `defmt` (default) or `plain`");

pub mod devices;
pub mod measure;
pub mod scenario {
    //! The scenarios: plant, sensor quantisation, schedule and seeds in one place.
    pub mod scooter;
    pub mod wheel;
}

#[cfg(feature = "defmt")]
use defmt_semihosting as _;

#[doc(hidden)]
pub use cortex_m_semihosting as __semihosting;
#[cfg(feature = "defmt")]
#[doc(hidden)]
pub use defmt as __defmt;

/// Prints one line over semihosting: a defmt frame in the default build, text in `plain`.
/// Use only `{}` placeholders with integers, floats and `&str` (valid in both syntaxes).
#[macro_export]
macro_rules! say {
    ($($arg:tt)*) => {{
        #[cfg(feature = "plain")]
        $crate::__semihosting::hprintln!($($arg)*);
        #[cfg(not(feature = "plain"))]
        $crate::__defmt::println!($($arg)*);
    }};
}

/// Reports a failure and exits QEMU with a failing status.
pub fn fail(what: &str, step: u32) -> ! {
    say!("FAIL {} at step {}", what, step);
    measure::exit(false)
}

#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    say!("FAIL panic");
    measure::exit(false)
}
