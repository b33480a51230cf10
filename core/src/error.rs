//! The one error type of the core: small, `Copy`, and explicit about what the filter did.

use core::fmt;

/// What went wrong in a core call. Unless a variant says otherwise, the object the call was
/// made on is left exactly as it was before the call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// A measurement sample was NaN or infinite.
    NonFiniteMeasurement,
    /// An input sample was NaN or infinite.
    NonFiniteInput,
    /// The measurement slice had the wrong number of channels.
    MeasurementLength { expected: usize, got: usize },
    /// The input slice had the wrong number of channels.
    InputLength { expected: usize, got: usize },
    /// The time step was zero, negative or not finite.
    InvalidTimeStep,
    /// A configuration value was out of its valid range (names the parameter).
    InvalidParameter(&'static str),
    /// A covariance matrix was not positive definite (Cholesky failed); no substitute used.
    NotPositiveDefinite,
    /// Every propagated state was non-finite: the model diverged for every particle/sigma point.
    NonFiniteState,
    /// The prediction horizon ended before the end-of-life threshold for every sample.
    HorizonExceeded,
    /// A sample was outside the physically valid range of the named channel.
    OutOfRange(&'static str),
    /// Not enough data for the requested operation (e.g. an empty window).
    InsufficientData,
    /// A statically allocated placeholder was used before it was reset with a configuration.
    NotConfigured,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::NonFiniteMeasurement => {
                f.write_str("measurement is NaN or infinite; sample rejected, filter unchanged")
            }
            Error::NonFiniteInput => {
                f.write_str("input is NaN or infinite; sample rejected, filter unchanged")
            }
            Error::MeasurementLength { expected, got } => write!(
                f,
                "measurement has {got} channels, expected {expected}; sample rejected, filter unchanged"
            ),
            Error::InputLength { expected, got } => write!(
                f,
                "input has {got} channels, expected {expected}; sample rejected, filter unchanged"
            ),
            Error::InvalidTimeStep => {
                f.write_str("time step is not a positive finite number; filter unchanged")
            }
            Error::InvalidParameter(name) => write!(f, "invalid parameter `{name}`"),
            Error::NotPositiveDefinite => f.write_str(
                "covariance is not positive definite (Cholesky failed); filter unchanged",
            ),
            Error::NonFiniteState => f.write_str(
                "model produced a non-finite state for every sample; step discarded, filter unchanged",
            ),
            Error::HorizonExceeded => {
                f.write_str("no sample reached end of life within the prediction horizon")
            }
            Error::OutOfRange(name) => {
                write!(f, "`{name}` is outside its valid range; sample rejected")
            }
            Error::InsufficientData => f.write_str("not enough data for this operation"),
            Error::NotConfigured => {
                f.write_str("filter is an unset placeholder; reset it with a configuration first")
            }
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for Error {}

/// Checks a time step: positive and finite.
#[inline]
pub fn check_dt<T: crate::Real>(dt: T) -> Result<(), Error> {
    if dt.finite() && dt > T::zero() {
        Ok(())
    } else {
        Err(Error::InvalidTimeStep)
    }
}
