//! Why the controller started ([`ResetCause`], reported by `kincal info`).
//!
//! Before the firmware resets itself (panic, processor fault, watchdog warning, reset request)
//! it writes the cause into a RAM word that start-up code does not zero (`.uninit`); the next
//! start reads it and overwrites it with [`ResetCause::Unknown`], so a later reset nobody
//! recorded is reported as unknown, never as the previous cause. A power-on leaves the word
//! random (zero on QEMU), which does not carry the tag. The STM32 board adds its reset flags
//! (RCC_CSR) through [`stm32_cause`].

use kincal_protocol::messages::ResetCause;

/// Upper half of a recorded word ("kc"); the lower byte is the cause.
const TAG: u32 = 0x6B63_5200;

/// Every cause, in the order of their `u8` values.
const CAUSES: [ResetCause; 8] = [
    ResetCause::PowerOn,
    ResetCause::Watchdog,
    ResetCause::Panic,
    ResetCause::Fault,
    ResetCause::Software,
    ResetCause::BrownOut,
    ResetCause::Pin,
    ResetCause::Unknown,
];

/// The RAM word that records `cause`.
pub const fn note(cause: ResetCause) -> u32 {
    TAG | cause as u32
}

/// The cause a RAM word records, if it records one.
pub fn from_note(word: u32) -> Option<ResetCause> {
    if word & !0xFF != TAG {
        return None;
    }
    CAUSES.get((word & 0xFF) as usize).copied()
}

/// The STM32F4's reset flags (RCC_CSR), as read at start.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stm32ResetFlags {
    /// IWDGRSTF: the independent watchdog.
    pub independent_watchdog: bool,
    /// SFTRSTF: a software reset (SYSRESETREQ).
    pub software: bool,
    /// PORRSTF: power-on or power-down reset.
    pub power_on: bool,
    /// BORRSTF: brown-out (also set at power-on).
    pub brown_out: bool,
    /// PINRSTF: the NRST pin (also set by every other reset, which drives it).
    pub pin: bool,
}

/// The cause from the STM32's flags and the recorded word (`note`, if it carried one): the
/// watchdog first, then a software reset as recorded (panic, fault, request), then power-on,
/// brown-out and the pin alone.
pub fn stm32_cause(flags: Stm32ResetFlags, recorded: Option<ResetCause>) -> ResetCause {
    if flags.independent_watchdog {
        ResetCause::Watchdog
    } else if flags.software {
        match recorded {
            Some(cause @ (ResetCause::Panic | ResetCause::Fault | ResetCause::Software)) => cause,
            _ => ResetCause::Software,
        }
    } else if flags.power_on {
        ResetCause::PowerOn
    } else if flags.brown_out {
        ResetCause::BrownOut
    } else if flags.pin {
        ResetCause::Pin
    } else {
        ResetCause::Unknown
    }
}

/// The reset-cause word of the boards: in `.uninit` RAM, which cortex-m-rt's start-up does not
/// zero and a system reset (or QEMU's) keeps.
#[cfg(any(feature = "board-mps2", feature = "board-stm32"))]
mod word {
    use core::mem::MaybeUninit;

    #[unsafe(link_section = ".uninit.KINCAL_RESET_CAUSE")]
    static mut RESET_CAUSE_WORD: MaybeUninit<u32> = MaybeUninit::uninit();

    /// The word as it is.
    pub fn read() -> u32 {
        // SAFETY: a 4-byte aligned word of RAM owned by this module; any bit pattern is a valid
        // u32 (uninitialised RAM reads as whatever it holds). A single word load cannot tear.
        unsafe { core::ptr::read_volatile(core::ptr::addr_of!(RESET_CAUSE_WORD).cast::<u32>()) }
    }

    /// Overwrite the word.
    pub fn write(value: u32) {
        // SAFETY: as in `read`; a single aligned word store cannot tear, and whoever interrupts
        // a store only writes the same word before resetting.
        unsafe { core::ptr::write_volatile(core::ptr::addr_of_mut!(RESET_CAUSE_WORD).cast::<u32>(), value) }
    }
}

/// What the word recorded for this start (`None`: nothing, e.g. after power-on), leaving
/// [`ResetCause::Unknown`] recorded for the next one.
#[cfg(any(feature = "board-mps2", feature = "board-stm32"))]
pub fn take_recorded() -> Option<ResetCause> {
    let recorded = from_note(word::read());
    record(ResetCause::Unknown);
    recorded
}

/// Record `cause` for the next start.
#[cfg(any(feature = "board-mps2", feature = "board-stm32"))]
pub fn record(cause: ResetCause) {
    word::write(note(cause));
}

/// Record `cause` and reset the controller.
#[cfg(any(feature = "board-mps2", feature = "board-stm32"))]
pub fn reset_because(cause: ResetCause) -> ! {
    record(cause);
    cortex_m::peripheral::SCB::sys_reset()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_cause_round_trips_and_other_words_are_no_record() {
        for cause in CAUSES {
            assert_eq!(from_note(note(cause)), Some(cause));
        }
        for word in [0, u32::MAX, 0xDEAD_BEEF, TAG | 8, note(ResetCause::Panic) ^ 0x100] {
            assert_eq!(from_note(word), None, "{word:08x}");
        }
    }

    #[test]
    fn stm32_flags_and_the_record_give_the_cause() {
        let f = Stm32ResetFlags::default();
        let por = Stm32ResetFlags { power_on: true, brown_out: true, pin: true, ..f };
        assert_eq!(stm32_cause(por, None), ResetCause::PowerOn);
        let panic = Stm32ResetFlags { software: true, pin: true, ..f };
        assert_eq!(stm32_cause(panic, Some(ResetCause::Panic)), ResetCause::Panic);
        assert_eq!(stm32_cause(panic, Some(ResetCause::Unknown)), ResetCause::Software, "a debugger's reset");
        let dog = Stm32ResetFlags { independent_watchdog: true, pin: true, ..f };
        assert_eq!(stm32_cause(dog, Some(ResetCause::Unknown)), ResetCause::Watchdog);
        assert_eq!(
            stm32_cause(Stm32ResetFlags { brown_out: true, pin: true, ..f }, None),
            ResetCause::BrownOut
        );
        assert_eq!(stm32_cause(Stm32ResetFlags { pin: true, ..f }, None), ResetCause::Pin);
        assert_eq!(stm32_cause(f, None), ResetCause::Unknown);
    }
}
