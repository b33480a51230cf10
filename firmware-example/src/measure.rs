//! Measurement glue: instruction counts from SysTick, the painted-stack high-water mark, and
//! the semihosting exit. The only `unsafe` of the firmware (besides the HardFault handler,
//! which cortex-m-rt requires to be `unsafe fn`) is the stack scan here.

use cortex_m::peripheral::SYST;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_semihosting::debug::{self, EXIT_FAILURE, EXIT_SUCCESS};

/// Instructions per SysTick tick under `qemu -icount shift=0` (1 ns per instruction) with
/// the mps2 core clock of 25 MHz.
pub const INSTRUCTIONS_PER_TICK: u32 = 40;
const SYST_MASK: u32 = 0x00FF_FFFF;

/// SysTick as a free-running 24-bit down-counter on the core clock.
pub struct InstructionCounter {
    _syst: SYST,
}

impl InstructionCounter {
    /// Starts SysTick at its full reload (wraps every 16.7 M ticks = 671 M instructions).
    pub fn new(mut syst: SYST) -> Self {
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(SYST_MASK);
        syst.clear_current();
        syst.enable_counter();
        Self { _syst: syst }
    }

    /// The counter now (ticks, counting down).
    #[inline(always)]
    pub fn now(&self) -> u32 {
        SYST::get_current()
    }

    /// Instructions from `start` to now (one wrap at most in between).
    #[inline(always)]
    pub fn since(&self, start: u32) -> u32 {
        (start.wrapping_sub(self.now()) & SYST_MASK) * INSTRUCTIONS_PER_TICK
    }
}

/// Worst and mean of per-step instruction counts.
#[derive(Clone, Copy, Debug, Default)]
pub struct StepStats {
    pub worst: u32,
    pub worst_step: u32,
    pub total: u64,
    pub count: u32,
}

impl StepStats {
    pub fn record(&mut self, step: u32, instructions: u32) {
        if instructions > self.worst {
            self.worst = instructions;
            self.worst_step = step;
        }
        self.total += u64::from(instructions);
        self.count += 1;
    }

    pub fn mean(&self) -> u32 {
        if self.count == 0 {
            0
        } else {
            (self.total / u64::from(self.count)) as u32
        }
    }
}

#[allow(unsafe_code)]
mod stack {
    unsafe extern "C" {
        static _stack_start: u32;
        static _stack_end: u32;
    }

    /// Bytes of stack ever used: cortex-m-rt painted `_stack_end.._stack_start` with
    /// `STACK_PAINT_VALUE` before `main`; the lowest overwritten word marks the deepest use.
    pub fn high_water() -> u32 {
        let top = core::ptr::addr_of!(_stack_start) as usize;
        let bottom = core::ptr::addr_of!(_stack_end) as usize;
        let mut p = bottom;
        while p < top {
            // SAFETY: `p` is a word-aligned address inside the RAM reserved for the stack
            // (between the two linker symbols); reading it has no side effects.
            let word = unsafe { core::ptr::read_volatile(p as *const u32) };
            if word != cortex_m_rt::STACK_PAINT_VALUE {
                break;
            }
            p += 4;
        }
        (top - p) as u32
    }

    /// Paints the unused stack again (everything more than 64 bytes below the current stack
    /// pointer), so that a later [`high_water`] sees only what was used after this call.
    pub fn repaint() {
        let bottom = core::ptr::addr_of!(_stack_end) as usize;
        let limit = (cortex_m::register::msp::read() as usize).saturating_sub(64) & !3;
        let mut p = bottom;
        while p < limit {
            // SAFETY: `p` lies between the bottom of the stack region and below the live
            // frames (64 bytes under the stack pointer; no interrupt handler is enabled), so
            // nothing reads this memory before it is written again.
            unsafe { core::ptr::write_volatile(p as *mut u32, cortex_m_rt::STACK_PAINT_VALUE) };
            p += 4;
        }
    }
}

pub use stack::{high_water as stack_high_water, repaint as repaint_stack};

/// Ends the QEMU run with a passing or failing status.
pub fn exit(pass: bool) -> ! {
    debug::exit(if pass { EXIT_SUCCESS } else { EXIT_FAILURE });
    loop {
        cortex_m::asm::bkpt();
    }
}
