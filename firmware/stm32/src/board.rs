//! `BoardHal`: the `gonio_firmware::Hal` of the Black Pill. Pins only; every decision (when to step,
//! which way, what a closed switch means) is the controller's.
//!
//! - STEP/DIR/ENABLE per axis on GPIO outputs (README pin table); ENABLE is driven active (low) at
//!   start-up, so the motors hold torque from boot.
//! - Home/limit switches on inputs with pull-ups, active low, read as levels when the controller asks.
//! - The detector is the **simple internal-ADC driver**: ADC1 on PA4..PA7, read with blocking
//!   conversions once the exposure time has elapsed (see [`BoardHal::poll_readout`]). The ADS131M04
//!   on SPI1 is the planned precision option (README).

use embassy_stm32::adc::{Adc, AnyAdcChannel, SampleTime};
use embassy_stm32::gpio::{Input, Output};
use embassy_stm32::peripherals::ADC1;
use embassy_time::Instant;
use gonio_firmware::{Hal, Readout};
use gonio_shared::Axis;

/// SYSCLK; the busy-wait delays below are counted in its cycles.
pub const SYSCLK_HZ: u32 = 96_000_000;
const CYCLES_PER_US: u32 = SYSCLK_HZ / 1_000_000;
/// STEP high time: 5 us, above every common driver's minimum (DRV8825 1.9 us, A4988 1 us, TMC 100 ns).
const STEP_PULSE_CYCLES: u32 = CYCLES_PER_US * 5;
/// DIR setup before the next STEP edge: 1 us (DRV8825 650 ns, A4988 200 ns, TMC 20 ns).
const DIR_SETUP_CYCLES: u32 = CYCLES_PER_US;

/// Conversions summed per channel at the end of an exposure.
pub const ADC_OVERSAMPLE: u32 = 8;
/// 144 ADC cycles + 12 = 6.5 us per conversion at the 24 MHz ADC clock (PCLK2 96 MHz / 4): ample for
/// a low-impedance source such as a transimpedance amplifier's output.
const ADC_SAMPLE_TIME: SampleTime = SampleTime::CYCLES144;

/// The four axes' pins, indexed by `Axis::index`.
pub struct AxisPins {
    pub step: [Output<'static>; 4],
    pub dir: [Output<'static>; 4],
    /// Held low (driver enabled) for as long as the binary runs: owned, never written again.
    #[allow(dead_code, reason = "kept only so the pins stay driven")]
    pub enable: [Output<'static>; 4],
    /// Home / limit switch, closed = low.
    pub limit: [Input<'static>; 4],
}

pub struct Detector {
    pub adc: Adc<'static, ADC1>,
    /// One per reported channel (`gonio_shared::msg::caps::MAX_CHANNELS` = 4).
    pub channels: [AnyAdcChannel<'static, ADC1>; 4],
}

#[derive(Clone, Copy)]
struct Exposure {
    done_us: u64,
    exposure_us: u32,
}

pub struct BoardHal {
    pins: AxisPins,
    /// Last level written to each DIR pin, so the setup delay is only paid on a change.
    dir_increasing: [Option<bool>; 4],
    detector: Detector,
    exposure: Option<Exposure>,
}

impl BoardHal {
    pub fn new(pins: AxisPins, detector: Detector) -> Self {
        Self {
            pins,
            dir_increasing: [None; 4],
            detector,
            exposure: None,
        }
    }

    /// One conversion pass over every channel, `ADC_OVERSAMPLE` times, summed per channel, then
    /// scaled by the exposure so the counts grow with exposure time like an integrating detector's:
    /// `counts = sum * exposure_us / 1000` = mean 12-bit code x 8 x exposure in ms (saturating).
    fn read_detector(&mut self, exposure_us: u32) -> Readout {
        let mut sums = [0u32; 4];
        for _ in 0..ADC_OVERSAMPLE {
            for (sum, channel) in sums.iter_mut().zip(self.detector.channels.iter_mut()) {
                *sum += u32::from(self.detector.adc.blocking_read(channel, ADC_SAMPLE_TIME));
            }
        }
        let mut readout = Readout::new();
        for sum in sums {
            let scaled = u64::from(sum) * u64::from(exposure_us) / 1000;
            // Cannot fail: `sums` has exactly MAX_CHANNELS entries.
            let _ = readout.push(u32::try_from(scaled).unwrap_or(u32::MAX));
        }
        readout
    }
}

impl Hal for BoardHal {
    fn now_us(&self) -> u64 {
        Instant::now().as_micros()
    }

    /// DIR high = increasing step count. To reverse an axis, swap one coil pair of its motor.
    fn set_direction(&mut self, axis: Axis, increasing: bool) {
        let i = axis.index();
        let (Some(pin), Some(last)) = (self.pins.dir.get_mut(i), self.dir_increasing.get_mut(i)) else {
            return;
        };
        if *last == Some(increasing) {
            return;
        }
        pin.set_level(increasing.into());
        *last = Some(increasing);
        cortex_m::asm::delay(DIR_SETUP_CYCLES);
    }

    /// One STEP pulse. Busy-waits a few microseconds: shorter than any await would be.
    fn step(&mut self, axis: Axis) {
        if let Some(pin) = self.pins.step.get_mut(axis.index()) {
            pin.set_high();
            cortex_m::asm::delay(STEP_PULSE_CYCLES);
            pin.set_low();
        }
    }

    fn limit_closed(&self, axis: Axis) -> bool {
        self.pins.limit.get(axis.index()).is_some_and(Input::is_low)
    }

    fn start_exposure(&mut self, exposure_us: u32) {
        self.exposure = Some(Exposure {
            done_us: self.now_us().saturating_add(u64::from(exposure_us)),
            exposure_us,
        });
    }

    /// `None` until the exposure time has passed; then the blocking ADC reads (4 channels x
    /// `ADC_OVERSAMPLE` conversions, about 0.3 ms) and the readout.
    fn poll_readout(&mut self) -> Option<Readout> {
        let exposure = self.exposure?;
        if self.now_us() < exposure.done_us {
            return None;
        }
        self.exposure = None;
        Some(self.read_detector(exposure.exposure_us))
    }
}
