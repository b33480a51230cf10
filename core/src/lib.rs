//! Prognos estimator core: `no_std`, allocation-free model-based prognostics.
//!
//! Every buffer is a fixed-size array sized by const generics; every function that can see bad
//! data returns [`Error`] instead of panicking. Scalars are generic over [`Real`] (f32 on the
//! Cortex-M4F, f64 on the host).
#![no_std]
#![forbid(unsafe_code)]
// `!(a < b)` is how NaN is rejected along with out-of-range values: deliberate.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::arithmetic_side_effects
    )
)]

#[cfg(feature = "std")]
extern crate std;

pub mod diagnose;
pub mod error;
pub mod fastmath;
pub mod filter;
pub mod health;
pub mod learn;
pub mod metrics;
pub mod model;
pub mod pipeline;
pub mod plants;
pub mod prognose;
pub mod random;
pub mod real;

pub use error::Error;
pub use real::{Real, cast};

pub mod safeguard;
pub mod stats;
