//! Sensor and instrument effects, each a small type behind the `Effect` trait, applied to one
//! reading at a time (a pixel of a render, or one detector reading of the virtual gonio).
//!
//! A pipeline is built only from the tables a scene's `[effects]` lists: an effect that is not
//! listed is not constructed, draws no random numbers and costs nothing; with none listed the
//! pipeline is empty and `apply_image` returns without touching the image.
//!
//! Order, physical: the light's drift scales what reaches the sensor, then exposure turns radiance
//! into signal, photon (shot) noise, read noise, the dark offset, and last the ADC's quantisation
//! and saturation. (The issue lists drift last; applied after the ADC it would produce values
//! between ADC codes and noise that does not scale with the light, so it goes first here.)
//!
//! Randomness: each random effect draws from its own stream, seeded by (pipeline seed, the effect's
//! fixed stream id, reading index). Results are therefore the same for any thread count, and adding
//! or removing one effect never shifts the random numbers another effect sees.

use super::image::Image;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson};
use rayon::prelude::*;
use serde::Deserialize;
use std::fmt::Debug;

/// When and which reading this is: the index selects the random streams, the time drives drift.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reading {
    pub index: u64,
    /// Seconds since the start of the acquisition.
    pub time_s: f64,
}

/// One effect on one reading. `channels` holds the reading's values (1 for a photodiode, 3 for RGB).
pub trait Effect: Send + Sync + Debug {
    /// The scene key of this effect, e.g. "shot_noise".
    fn name(&self) -> &'static str;
    /// `Some(stream id)` if the effect draws random numbers; the id must be unique among effects.
    fn random_stream(&self) -> Option<u64>;
    /// Apply to the reading. `rng` is this effect's stream for this reading (`None` for
    /// deterministic effects, which never receive one).
    fn apply(&self, channels: &mut [f64], reading: Reading, rng: Option<&mut ChaCha8Rng>);
}

/// Radiance -> signal: signal = scale x value.
#[derive(Clone, Debug, PartialEq)]
pub struct Exposure {
    pub scale: f64,
}

impl Effect for Exposure {
    fn name(&self) -> &'static str {
        "exposure"
    }
    fn random_stream(&self) -> Option<u64> {
        None
    }
    fn apply(&self, channels: &mut [f64], _: Reading, _: Option<&mut ChaCha8Rng>) {
        channels.iter_mut().for_each(|v| *v *= self.scale);
    }
}

/// Photon noise: the signal, in units where one unit is `photons_per_unit` photons, becomes
/// Poisson(value x photons_per_unit) / photons_per_unit, so its variance is value / photons_per_unit
/// (in photon counts: variance = mean).
#[derive(Clone, Debug, PartialEq)]
pub struct ShotNoise {
    pub photons_per_unit: f64,
}

/// Above this mean photon count the Poisson draw is replaced by a normal one with the same mean and
/// variance: the two agree to far below any measurable difference there, and rand_distr's Poisson
/// refuses means above its MAX_LAMBDA (about 1.8e19).
const POISSON_NORMAL_SWITCH: f64 = 1e12;

impl Effect for ShotNoise {
    fn name(&self) -> &'static str {
        "shot_noise"
    }
    fn random_stream(&self) -> Option<u64> {
        Some(2)
    }
    fn apply(&self, channels: &mut [f64], _: Reading, rng: Option<&mut ChaCha8Rng>) {
        let Some(rng) = rng else { return };
        for v in channels.iter_mut() {
            let mean = *v * self.photons_per_unit;
            // Guard: no photons (or a negative/NaN signal) -> no counts; Poisson needs a positive mean.
            if !(mean > 0.0) {
                *v = 0.0;
                continue;
            }
            let count = if mean < POISSON_NORMAL_SWITCH {
                Poisson::new(mean).map(|p| p.sample(rng)).unwrap_or(mean)
            } else {
                Normal::new(mean, mean.sqrt()).map(|n| n.sample(rng)).unwrap_or(mean)
            };
            *v = count / self.photons_per_unit;
        }
    }
}

/// Gaussian read noise of standard deviation `sigma` (signal units), independent per channel.
#[derive(Clone, Debug, PartialEq)]
pub struct ReadNoise {
    pub sigma: f64,
}

impl Effect for ReadNoise {
    fn name(&self) -> &'static str {
        "read_noise"
    }
    fn random_stream(&self) -> Option<u64> {
        Some(3)
    }
    fn apply(&self, channels: &mut [f64], _: Reading, rng: Option<&mut ChaCha8Rng>) {
        let Some(rng) = rng else { return };
        // sigma is validated finite and >= 0, so the distribution always exists.
        let Ok(normal) = Normal::new(0.0, self.sigma) else {
            return;
        };
        channels.iter_mut().for_each(|v| *v += normal.sample(rng));
    }
}

/// A constant dark signal added to every reading (signal units).
#[derive(Clone, Debug, PartialEq)]
pub struct DarkOffset {
    pub level: f64,
}

impl Effect for DarkOffset {
    fn name(&self) -> &'static str {
        "dark_offset"
    }
    fn random_stream(&self) -> Option<u64> {
        None
    }
    fn apply(&self, channels: &mut [f64], _: Reading, _: Option<&mut ChaCha8Rng>) {
        channels.iter_mut().for_each(|v| *v += self.level);
    }
}

/// An ADC of `bits` bits spanning [0, full_scale]: values are clamped (saturation at full scale,
/// nothing below 0) and rounded to the nearest of 2^bits - 1 steps. The reading keeps signal units
/// (code x step); `code` gives the integer.
#[derive(Clone, Debug, PartialEq)]
pub struct Adc {
    pub bits: u32,
    pub full_scale: f64,
}

impl Adc {
    fn max_code(&self) -> f64 {
        // bits is validated to 1..=32.
        ((1u64 << self.bits) - 1) as f64
    }

    /// The integer code of a signal value (NaN reads as 0).
    pub fn code(&self, value: f64) -> u32 {
        let x = if value.is_nan() {
            0.0
        } else {
            (value / self.full_scale).clamp(0.0, 1.0)
        };
        (x * self.max_code()).round() as u32
    }

    /// One ADC step in signal units.
    pub fn step(&self) -> f64 {
        self.full_scale / self.max_code()
    }
}

impl Effect for Adc {
    fn name(&self) -> &'static str {
        "adc"
    }
    fn random_stream(&self) -> Option<u64> {
        None
    }
    fn apply(&self, channels: &mut [f64], _: Reading, _: Option<&mut ChaCha8Rng>) {
        channels
            .iter_mut()
            .for_each(|v| *v = self.code(*v) as f64 * self.step());
    }
}

/// Slow change of the light's intensity: factor(t) = max(0, 1 + rate_per_s t + amplitude sin(2 pi t / period_s)).
#[derive(Clone, Debug, PartialEq)]
pub struct Drift {
    pub rate_per_s: f64,
    pub amplitude: f64,
    pub period_s: f64,
}

impl Drift {
    pub fn factor(&self, time_s: f64) -> f64 {
        // period_s is validated > 0, so the sine's argument is finite for finite t.
        let f =
            1.0 + self.rate_per_s * time_s + self.amplitude * (std::f64::consts::TAU * time_s / self.period_s).sin();
        if f.is_finite() {
            f.max(0.0)
        } else {
            1.0
        }
    }
}

impl Effect for Drift {
    fn name(&self) -> &'static str {
        "drift"
    }
    fn random_stream(&self) -> Option<u64> {
        None
    }
    fn apply(&self, channels: &mut [f64], reading: Reading, _: Option<&mut ChaCha8Rng>) {
        let f = self.factor(reading.time_s);
        channels.iter_mut().for_each(|v| *v *= f);
    }
}

/// The `[effects]` table of a scene file; every sub-table is optional.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EffectsConfig {
    pub exposure: Option<ExposureConfig>,
    pub shot_noise: Option<ShotNoiseConfig>,
    pub read_noise: Option<ReadNoiseConfig>,
    pub dark_offset: Option<DarkOffsetConfig>,
    pub adc: Option<AdcConfig>,
    pub drift: Option<DriftConfig>,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExposureConfig {
    pub scale: f64,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShotNoiseConfig {
    pub photons_per_unit: f64,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReadNoiseConfig {
    pub sigma: f64,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DarkOffsetConfig {
    pub level: f64,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AdcConfig {
    pub bits: u32,
    pub full_scale: f64,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriftConfig {
    #[serde(default)]
    pub rate_per_s: f64,
    #[serde(default)]
    pub amplitude: f64,
    #[serde(default = "default_period")]
    pub period_s: f64,
    /// Images only: a render is read out as a raster scan, pixel i at time i x pixel_time_s.
    #[serde(default = "default_pixel_time")]
    pub pixel_time_s: f64,
}

fn default_period() -> f64 {
    600.0
}

fn default_pixel_time() -> f64 {
    1e-3
}

/// The effects a scene asked for, in application order.
#[derive(Debug, Default)]
pub struct EffectPipeline {
    effects: Vec<Box<dyn Effect>>,
    seed: u64,
    /// Seconds between consecutive pixels when applied to an image (from the drift table).
    pixel_time_s: f64,
}

impl EffectPipeline {
    /// Build from a scene's `[effects]`; an error names the key and the bad value.
    pub fn from_config(cfg: &EffectsConfig, seed: u64) -> Result<Self, String> {
        let finite = |key: &str, v: f64| {
            if v.is_finite() {
                Ok(v)
            } else {
                Err(format!("effects.{key} must be finite, got {v}"))
            }
        };
        let non_negative = |key: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(v)
            } else {
                Err(format!("effects.{key} must be finite and >= 0, got {v}"))
            }
        };
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(v)
            } else {
                Err(format!("effects.{key} must be finite and > 0, got {v}"))
            }
        };
        let mut effects: Vec<Box<dyn Effect>> = Vec::new();
        let mut pixel_time_s = 0.0;
        if let Some(d) = &cfg.drift {
            effects.push(Box::new(Drift {
                rate_per_s: finite("drift.rate_per_s", d.rate_per_s)?,
                amplitude: finite("drift.amplitude", d.amplitude)?,
                period_s: positive("drift.period_s", d.period_s)?,
            }));
            pixel_time_s = non_negative("drift.pixel_time_s", d.pixel_time_s)?;
        }
        if let Some(e) = &cfg.exposure {
            effects.push(Box::new(Exposure {
                scale: non_negative("exposure.scale", e.scale)?,
            }));
        }
        if let Some(s) = &cfg.shot_noise {
            effects.push(Box::new(ShotNoise {
                photons_per_unit: positive("shot_noise.photons_per_unit", s.photons_per_unit)?,
            }));
        }
        if let Some(r) = &cfg.read_noise {
            effects.push(Box::new(ReadNoise {
                sigma: non_negative("read_noise.sigma", r.sigma)?,
            }));
        }
        if let Some(d) = &cfg.dark_offset {
            effects.push(Box::new(DarkOffset {
                level: finite("dark_offset.level", d.level)?,
            }));
        }
        if let Some(a) = &cfg.adc {
            if !(1..=32).contains(&a.bits) {
                return Err(format!("effects.adc.bits must be 1..=32, got {}", a.bits));
            }
            effects.push(Box::new(Adc {
                bits: a.bits,
                full_scale: positive("adc.full_scale", a.full_scale)?,
            }));
        }
        Ok(Self {
            effects,
            seed,
            pixel_time_s,
        })
    }

    pub fn is_empty(&self) -> bool {
        self.effects.is_empty()
    }

    /// The names of the constructed effects, in order.
    pub fn names(&self) -> Vec<&'static str> {
        self.effects.iter().map(|e| e.name()).collect()
    }

    /// Apply every effect to one reading.
    pub fn apply_reading(&self, channels: &mut [f64], reading: Reading) {
        for effect in &self.effects {
            match effect.random_stream() {
                Some(stream) => {
                    let mut rng = ChaCha8Rng::seed_from_u64(stream_seed(self.seed, stream, reading.index));
                    effect.apply(channels, reading, Some(&mut rng));
                }
                None => effect.apply(channels, reading, None),
            }
        }
    }

    /// Apply to every pixel of an image (reading index = raster index). Empty pipeline: no-op.
    pub fn apply_image(&self, image: &mut Image) {
        if self.is_empty() {
            return;
        }
        image.pixels.par_iter_mut().enumerate().for_each(|(i, p)| {
            let mut c = [p.x, p.y, p.z];
            let reading = Reading {
                index: i as u64,
                time_s: i as f64 * self.pixel_time_s,
            };
            self.apply_reading(&mut c, reading);
            *p = glam::DVec3::from_array(c);
        });
    }
}

/// SplitMix64's finaliser: a well-mixed 64-bit value from any input.
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The seed of one random stream for one reading.
pub(crate) fn stream_seed(seed: u64, stream: u64, index: u64) -> u64 {
    mix64(mix64(mix64(seed) ^ stream) ^ index)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn stats(values: &[f64]) -> (f64, f64) {
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
        (mean, var)
    }

    fn readings(pipe: &EffectPipeline, value: f64, n: u64) -> Vec<f64> {
        (0..n)
            .map(|index| {
                let mut c = [value];
                pipe.apply_reading(&mut c, Reading { index, time_s: 0.0 });
                c[0]
            })
            .collect()
    }

    /// n = 20000 readings: the sample mean has standard error sigma / sqrt(n) and the sample variance
    /// a relative standard error of sqrt(2 / n) = 1% (Gaussian; slightly more for Poisson), so the
    /// tolerances below (5% on variances, 5 standard errors on means) fail only on a real mismatch.
    const N: u64 = 20_000;

    #[test]
    fn shot_noise_variance_equals_mean_in_photons() {
        let cfg = EffectsConfig {
            shot_noise: Some(ShotNoiseConfig {
                photons_per_unit: 100.0,
            }),
            ..Default::default()
        };
        let pipe = EffectPipeline::from_config(&cfg, 7).expect("valid");
        for value in [0.05, 0.5, 20.0] {
            let photons: Vec<f64> = readings(&pipe, value, N).iter().map(|v| v * 100.0).collect();
            let (mean, var) = stats(&photons);
            let expect = value * 100.0;
            eprintln!("shot noise: mean photons {expect}: sample mean {mean:.3}, variance {var:.3}");
            assert!(
                (mean - expect).abs() < 5.0 * (expect / N as f64).sqrt(),
                "{mean} vs {expect}"
            );
            assert!((var / expect - 1.0).abs() < 0.05, "variance {var} vs mean {expect}");
        }
    }

    #[test]
    fn read_noise_dark_offset_adc_and_drift_match_their_parameters() {
        let cfg = EffectsConfig {
            read_noise: Some(ReadNoiseConfig { sigma: 0.02 }),
            dark_offset: Some(DarkOffsetConfig { level: 0.1 }),
            ..Default::default()
        };
        let pipe = EffectPipeline::from_config(&cfg, 7).expect("valid");
        let (mean, var) = stats(&readings(&pipe, 0.3, N));
        eprintln!(
            "read noise sigma 0.02 + dark 0.1 on 0.3: mean {mean:.5}, sd {:.5}",
            var.sqrt()
        );
        assert!((mean - 0.4).abs() < 5.0 * 0.02 / (N as f64).sqrt());
        assert!((var / 0.0004 - 1.0).abs() < 0.05, "{var}");
        // The dark offset draws nothing: read noise alone gives the same draws, shifted by the offset.
        let alone = EffectPipeline::from_config(
            &EffectsConfig {
                read_noise: cfg.read_noise.clone(),
                ..Default::default()
            },
            7,
        )
        .expect("valid");
        for (a, b) in readings(&alone, 0.3, 100).iter().zip(readings(&pipe, 0.3, 100)) {
            assert!((a + 0.1 - b).abs() < 1e-12);
        }

        let mut c = [0.25, 3.0];
        Exposure { scale: 4.0 }.apply(&mut c, Reading { index: 0, time_s: 0.0 }, None);
        assert_eq!(c, [1.0, 12.0]);

        let adc = Adc {
            bits: 8,
            full_scale: 2.0,
        };
        assert_eq!(adc.code(-1.0), 0);
        assert_eq!(adc.code(5.0), 255, "saturates at full scale");
        assert_eq!(adc.code(f64::NAN), 0);
        assert_eq!(adc.code(1.0), 128, "1.0 / 2.0 * 255 = 127.5 rounds half away from zero");
        let mut c = [0.7, 3.0, -0.2];
        adc.apply(&mut c, Reading { index: 0, time_s: 0.0 }, None);
        assert!((c[0] - 89.0 * 2.0 / 255.0).abs() < 1e-15 && c[1] == 2.0 && c[2] == 0.0);
        // Quantisation error of a uniform ramp: at most half a step, variance step^2 / 12.
        let errs: Vec<f64> = (0..N)
            .map(|i| {
                let v = 1.9 * i as f64 / N as f64;
                adc.code(v) as f64 * adc.step() - v
            })
            .collect();
        assert!(errs.iter().all(|e| e.abs() <= 0.5 * adc.step() + 1e-12));
        let (_, var) = stats(&errs);
        assert!((var / (adc.step().powi(2) / 12.0) - 1.0).abs() < 0.05, "{var}");

        let drift = Drift {
            rate_per_s: 1e-3,
            amplitude: 0.05,
            period_s: 100.0,
        };
        assert_eq!(drift.factor(0.0), 1.0);
        assert!((drift.factor(25.0) - (1.0 + 0.025 + 0.05)).abs() < 1e-12);
        assert!((drift.factor(100.0) - 1.1).abs() < 1e-12);
        assert_eq!(
            Drift {
                rate_per_s: -1.0,
                amplitude: 0.0,
                period_s: 1.0
            }
            .factor(5.0),
            0.0
        );
    }

    #[test]
    fn only_listed_effects_are_built_in_physical_order_and_bad_values_are_named() {
        let empty = EffectPipeline::from_config(&EffectsConfig::default(), 1).expect("valid");
        assert!(empty.is_empty());
        let mut img = Image::new(2, 1);
        img.pixels[0] = DVec3::new(0.1, 0.2, 0.3);
        let before = img.clone();
        empty.apply_image(&mut img);
        assert_eq!(img, before);
        let all: EffectsConfig = toml::from_str(
            "exposure = { scale = 2.0 }\nshot_noise = { photons_per_unit = 1e4 }\nread_noise = { sigma = 0.01 }\n\
             dark_offset = { level = 0.01 }\nadc = { bits = 12, full_scale = 1.0 }\ndrift = { amplitude = 0.01 }",
        )
        .expect("parses");
        let pipe = EffectPipeline::from_config(&all, 1).expect("valid");
        assert_eq!(
            pipe.names(),
            ["drift", "exposure", "shot_noise", "read_noise", "dark_offset", "adc"]
        );
        let bad = EffectsConfig {
            adc: Some(AdcConfig {
                bits: 40,
                full_scale: 1.0,
            }),
            ..Default::default()
        };
        assert_eq!(
            EffectPipeline::from_config(&bad, 1).err().as_deref(),
            Some("effects.adc.bits must be 1..=32, got 40")
        );
        let bad = EffectsConfig {
            read_noise: Some(ReadNoiseConfig { sigma: -1.0 }),
            ..Default::default()
        };
        assert_eq!(
            EffectPipeline::from_config(&bad, 1).err().as_deref(),
            Some("effects.read_noise.sigma must be finite and >= 0, got -1")
        );
        assert!(toml::from_str::<EffectsConfig>("blur = { radius = 1 }").is_err());
    }
}
