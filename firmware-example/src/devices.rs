//! Simulated sensor front-ends on an I2C bus (`embedded-hal` 1.0) and their drivers.
//!
//! The plant latches each sample into a front-end's register bank as raw big-endian counts;
//! the pipeline reads them only through the driver, over the `I2c` trait, exactly as it would
//! read a real ADC or encoder interface (which is what a board would put in their place).
//! The conversion from counts is the scenario's (`scenario::*::convert`).

use crate::scenario::scooter::ScooterCounts;
use crate::scenario::wheel::WheelCounts;
use embedded_hal::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};

/// A read-only register bank on the bus: a write sets the register pointer, reads return
/// consecutive registers. Reading register `clear_on_read` clears bit 0 of register 0 (a
/// "data ready" flag), as real ADCs do.
pub struct SimulatedFrontEnd<const LEN: usize> {
    address: u8,
    bank: [u8; LEN],
    pointer: usize,
    clear_on_read: Option<usize>,
}

impl<const LEN: usize> SimulatedFrontEnd<LEN> {
    pub const fn new(address: u8, clear_on_read: Option<usize>) -> Self {
        Self {
            address,
            bank: [0; LEN],
            pointer: 0,
            clear_on_read,
        }
    }

    /// The plant side: the converter finished a sample.
    pub fn latch(&mut self, registers: [u8; LEN]) {
        self.bank = registers;
    }
}

impl<const LEN: usize> ErrorType for SimulatedFrontEnd<LEN> {
    type Error = ErrorKind;
}

impl<const LEN: usize> I2c for SimulatedFrontEnd<LEN> {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [Operation<'_>],
    ) -> Result<(), Self::Error> {
        if address != self.address {
            return Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address));
        }
        for operation in operations {
            match operation {
                Operation::Write(bytes) => match bytes {
                    [register] if usize::from(*register) < LEN => {
                        self.pointer = usize::from(*register)
                    }
                    _ => return Err(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Data)),
                },
                Operation::Read(buffer) => {
                    let end = self.pointer + buffer.len();
                    let Some(source) = self.bank.get(self.pointer..end) else {
                        return Err(ErrorKind::Overrun);
                    };
                    buffer.copy_from_slice(source);
                    if let Some(flagged) = self.clear_on_read
                        && (self.pointer..end).contains(&flagged)
                        && let Some(status) = self.bank.first_mut()
                    {
                        *status &= !1;
                    }
                    self.pointer = end;
                }
            }
        }
        Ok(())
    }
}

fn i24(bytes: [u8; 3]) -> i32 {
    // Sign-extend through the top byte of an i32.
    i32::from_be_bytes([bytes[0], bytes[1], bytes[2], 0]) >> 8
}

fn i24_bytes(value: i32) -> [u8; 3] {
    let b = value.to_be_bytes();
    [b[1], b[2], b[3]]
}

/// Reaction-wheel front-end: status (bit 0: gauge ready), current (i16), speed (i24), gauge
/// counter (u32).
pub mod wheel_map {
    pub const ADDRESS: u8 = 0x48;
    pub const STATUS: u8 = 0;
    pub const CURRENT: u8 = 1;
    pub const SPEED: u8 = 3;
    pub const GAUGE: u8 = 6;
    pub const LEN: usize = 10;
}

pub type WheelFrontEnd = SimulatedFrontEnd<{ wheel_map::LEN }>;

impl WheelFrontEnd {
    pub const fn wheel() -> Self {
        Self::new(wheel_map::ADDRESS, Some(wheel_map::GAUGE as usize))
    }

    /// Encodes counts into the register layout.
    pub fn latch_counts(&mut self, counts: &WheelCounts) {
        let mut r = [0u8; wheel_map::LEN];
        r[0] = u8::from(counts.gauge_ready);
        r[1..3].copy_from_slice(&counts.current.to_be_bytes());
        r[3..6].copy_from_slice(&i24_bytes(counts.speed));
        r[6..10].copy_from_slice(&counts.gauge.to_be_bytes());
        self.latch(r);
    }
}

/// Driver of the wheel front-end.
pub struct WheelDriver<I> {
    bus: I,
}

impl<I: I2c> WheelDriver<I> {
    pub fn new(bus: I) -> Self {
        Self { bus }
    }

    /// The simulation's access to the device behind the bus (to latch samples).
    pub fn bus_mut(&mut self) -> &mut I {
        &mut self.bus
    }

    /// Reads status, current and speed in one burst, and the gauge when it is ready.
    pub fn read(&mut self) -> Result<WheelCounts, I::Error> {
        let mut head = [0u8; 6];
        self.bus
            .write_read(wheel_map::ADDRESS, &[wheel_map::STATUS], &mut head)?;
        let gauge_ready = head[0] & 1 != 0;
        let mut gauge = [0u8; 4];
        if gauge_ready {
            self.bus
                .write_read(wheel_map::ADDRESS, &[wheel_map::GAUGE], &mut gauge)?;
        }
        Ok(WheelCounts {
            current: i16::from_be_bytes([head[1], head[2]]),
            speed: i24([head[3], head[4], head[5]]),
            gauge: u32::from_be_bytes(gauge),
            gauge_ready,
        })
    }
}

/// Scooter front-end: rear encoder, body speed, front encoder speeds (i24 each).
pub mod scooter_map {
    pub const ADDRESS: u8 = 0x36;
    pub const SPEEDS: u8 = 0;
    pub const LEN: usize = 9;
}

pub type ScooterFrontEnd = SimulatedFrontEnd<{ scooter_map::LEN }>;

impl ScooterFrontEnd {
    pub const fn scooter() -> Self {
        Self::new(scooter_map::ADDRESS, None)
    }

    pub fn latch_counts(&mut self, counts: &ScooterCounts) {
        let mut r = [0u8; scooter_map::LEN];
        for (chunk, c) in r.chunks_exact_mut(3).zip(counts) {
            chunk.copy_from_slice(&i24_bytes(*c));
        }
        self.latch(r);
    }
}

/// Driver of the scooter front-end.
pub struct ScooterDriver<I> {
    bus: I,
}

impl<I: I2c> ScooterDriver<I> {
    pub fn new(bus: I) -> Self {
        Self { bus }
    }

    pub fn bus_mut(&mut self) -> &mut I {
        &mut self.bus
    }

    pub fn read(&mut self) -> Result<ScooterCounts, I::Error> {
        let mut raw = [0u8; scooter_map::LEN];
        self.bus
            .write_read(scooter_map::ADDRESS, &[scooter_map::SPEEDS], &mut raw)?;
        let mut counts = [0i32; 3];
        for (c, chunk) in counts.iter_mut().zip(raw.chunks_exact(3)) {
            *c = i24([chunk[0], chunk[1], chunk[2]]);
        }
        Ok(counts)
    }
}
