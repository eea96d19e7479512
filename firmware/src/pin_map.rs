//! The Black Pill's stepper-driver pins (firmware/stm32/README.md, "Stepper drivers") and the GPIO
//! BSRR words computed from them: here, not in `firmware/stm32`, so host tests check the words the
//! board writes (every step event's, and the panic / HardFault path's) against this one map.

/// A GPIO port, numbered as the STM32 (and embassy's `Pin::port`) numbers them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Port {
    A = 0,
    B = 1,
}

/// One GPIO pin: its port and bit (0..=15).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pin {
    pub port: Port,
    pub bit: u8,
}

/// One axis's driver inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DriverPins {
    pub step: Pin,
    pub dir: Pin,
    pub enable: Pin,
}

const fn pb(bit: u8) -> Pin {
    Pin { port: Port::B, bit }
}

/// Indexed by `Axis::index` (light, detector, tilt, azimuth). Every pin on GPIOB, so one BSRR
/// write applies a step event's edges, and one write stops every driver.
pub const DRIVER_PINS: [DriverPins; 4] = [
    DriverPins {
        step: pb(0),
        dir: pb(12),
        enable: pb(8),
    },
    DriverPins {
        step: pb(1),
        dir: pb(13),
        enable: pb(9),
    },
    DriverPins {
        step: pb(6),
        dir: pb(14),
        enable: pb(4),
    },
    DriverPins {
        step: pb(7),
        dir: pb(15),
        enable: pb(10),
    },
];

/// The drivers' ENABLE input is active low (DRV8825, A4988, TMC22xx): high disables.
pub const ENABLE_ACTIVE_LOW: bool = true;

/// The port every STEP, DIR and ENABLE pin is on.
pub const DRIVER_PORT: Port = Port::B;

/// BSRR bits: the low half sets a pin, the high half resets it.
const fn set(pin: Pin) -> u32 {
    1 << pin.bit
}

const fn reset(pin: Pin) -> u32 {
    1 << (pin.bit + 16)
}

/// Axis `i`'s STEP pin as a BSRR set bit (its reset bit is 16 higher).
pub const STEP_BIT: [u32; 4] = [
    set(DRIVER_PINS[0].step),
    set(DRIVER_PINS[1].step),
    set(DRIVER_PINS[2].step),
    set(DRIVER_PINS[3].step),
];

/// Axis `i`'s DIR pin as a BSRR set bit.
pub const DIR_BIT: [u32; 4] = [
    set(DRIVER_PINS[0].dir),
    set(DRIVER_PINS[1].dir),
    set(DRIVER_PINS[2].dir),
    set(DRIVER_PINS[3].dir),
];

/// Axis bits (`1 << Axis::index`) to STEP pin bits (PB0, PB1, PB6, PB7). Bit arithmetic rather
/// than a loop over [`STEP_BIT`]: this runs in every step interrupt (tested against the map).
#[inline]
pub fn step_bits(axes: u8) -> u32 {
    let a = u32::from(axes);
    (a & 0b0011) | ((a & 0b1100) << 4)
}

/// Axis bits to DIR pin bits (PB12..PB15 in axis order; tested against the map).
#[inline]
pub fn dir_bits(axes: u8) -> u32 {
    u32::from(axes & 0b1111) << 12
}

/// The one [`DRIVER_PORT`] BSRR word a panic or a HardFault writes before the reset: every STEP
/// pin low and every driver disabled, nothing else touched.
pub const DRIVERS_OFF_BSRR: u32 = drivers_off_bsrr();

const fn drivers_off_bsrr() -> u32 {
    let mut word = 0;
    let mut i = 0;
    while i < DRIVER_PINS.len() {
        let p = DRIVER_PINS[i];
        word |= reset(p.step);
        word |= if ENABLE_ACTIVE_LOW {
            set(p.enable)
        } else {
            reset(p.enable)
        };
        i += 1;
    }
    word
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A GPIO port's output register after a BSRR write: set bits win over reset bits (RM0383).
    fn after_bsrr(odr: u16, word: u32) -> u16 {
        let (set, reset) = (word as u16, (word >> 16) as u16);
        (odr & !reset) | set
    }

    fn bit(odr: u16, pin: Pin) -> bool {
        odr & (1 << pin.bit) != 0
    }

    #[test]
    fn drivers_off_lowers_every_step_and_disables_every_driver_and_touches_nothing_else() {
        // Every pin the word must change is on the one port it is written to.
        for (axis, p) in DRIVER_PINS.iter().enumerate() {
            assert_eq!(p.step.port, DRIVER_PORT, "axis {axis}: STEP off the driver port");
            assert_eq!(p.enable.port, DRIVER_PORT, "axis {axis}: ENABLE off the driver port");
        }
        let ours: u16 = DRIVER_PINS
            .iter()
            .map(|p| (1 << p.step.bit) | (1 << p.enable.bit))
            .fold(0, |a, b| a | b);
        // From every output state of the port (all 2^16).
        for before in 0..=u16::MAX {
            let after = after_bsrr(before, DRIVERS_OFF_BSRR);
            for (axis, p) in DRIVER_PINS.iter().enumerate() {
                assert!(!bit(after, p.step), "axis {axis}: STEP left high from {before:#06x}");
                assert_eq!(
                    bit(after, p.enable),
                    ENABLE_ACTIVE_LOW,
                    "axis {axis}: driver left enabled from {before:#06x}"
                );
            }
            assert_eq!(after & !ours, before & !ours, "other pins changed from {before:#06x}");
        }
    }

    #[test]
    fn pins_are_distinct_and_on_the_driver_port() {
        let all: [Pin; 12] = core::array::from_fn(|i| {
            let p = DRIVER_PINS[i / 3];
            [p.step, p.dir, p.enable][i % 3]
        });
        for (i, a) in all.iter().enumerate() {
            assert_eq!(a.port, DRIVER_PORT, "{a:?}");
            assert!(a.bit < 16, "{a:?}");
            assert!(all[i + 1..].iter().all(|b| b != a), "{a:?} used twice");
        }
    }

    #[test]
    fn step_and_dir_bits_follow_the_map() {
        for axes in 0..=0b1111u8 {
            let on = |i: usize| axes & (1 << i) != 0;
            let step = (0..4)
                .filter(|&i| on(i))
                .map(|i| set(DRIVER_PINS[i].step))
                .fold(0, |a, b| a | b);
            let dir = (0..4)
                .filter(|&i| on(i))
                .map(|i| set(DRIVER_PINS[i].dir))
                .fold(0, |a, b| a | b);
            assert_eq!(step_bits(axes), step, "STEP bits of axes {axes:#06b}");
            assert_eq!(dir_bits(axes), dir, "DIR bits of axes {axes:#06b}");
        }
        for i in 0..4 {
            assert_eq!(STEP_BIT[i], step_bits(1 << i));
            assert_eq!(DIR_BIT[i], dir_bits(1 << i));
        }
    }
}
