use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn sphere_photo(spec: &str) -> Image {
    capture::render_capture(spec, 1.0).expect("render")
}

#[test]
fn preprocessing_ignores_light_intensity() {
    let img = sphere_photo("ward:rho_d=0.3,alpha=0.1");
    let base = preprocess(&img).expect("preprocess");
    // Factors that are not powers of two, so rounding is really exercised.
    for scale in [0.25 * 1.1, 0.7, 3.3, 4.0 * 0.97] {
        let mut scaled = img.clone();
        for p in &mut scaled.pixels {
            *p *= scale;
        }
        let other = preprocess(&scaled).expect("preprocess");
        let worst = base
            .iter()
            .zip(&other)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "x{scale}: inputs differ by {worst}");
    }
}

#[test]
fn preprocessing_rejects_black_and_nan_images() {
    let black = Image::new(16, 16);
    assert!(preprocess(&black).unwrap_err().contains("black"));
    let mut nan = sphere_photo("ward:rho_d=0.3,alpha=0.1");
    nan.pixels[7] = glam::DVec3::splat(f64::NAN);
    assert!(preprocess(&nan).unwrap_err().contains("NaN"));
}

#[test]
fn resampling_is_the_box_average_and_crops_to_a_square() {
    let mut img = Image::new(2 * INPUT_SIZE + 6, 2 * INPUT_SIZE);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for p in &mut img.pixels {
        *p = glam::DVec3::splat(rng.random::<f64>());
    }
    let small = resample_square(&img, INPUT_SIZE);
    for (ox, oy) in [(0, 0), (5, 9), (INPUT_SIZE - 1, INPUT_SIZE - 1)] {
        let mut sum = glam::DVec3::ZERO;
        for dy in 0..2 {
            for dx in 0..2 {
                sum += img.get(3 + 2 * ox + dx, 2 * oy + dy);
            }
        }
        assert!((small.get(ox, oy) - sum / 4.0).length() < 1e-12, "pixel ({ox}, {oy})");
    }
}

#[test]
fn vertical_flip_is_an_involution_and_matches_the_mirrored_render() {
    let img = sphere_photo("ggx:alpha=0.2,diffuse=0.2/0.1/0.05");
    // A ramp that differs in every row shows the flip moves rows and undoes itself.
    let ramp: Vec<f32> = (0..INPUT_LEN).map(|i| i as f32).collect();
    let flipped = flip_vertical(&ramp);
    assert_eq!(
        flipped[0],
        ramp[(INPUT_SIZE - 1) * INPUT_SIZE],
        "row 0 comes from the last row"
    );
    assert_eq!(flip_vertical(&flipped), ramp);
    let x = preprocess(&img).expect("preprocess");
    let f = flip_vertical(&x);
    // The capture light lies in y = 0, so the flipped photo is the photo itself (up to rendering noise).
    let worst = x.iter().zip(&f).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst < 1e-3, "top and bottom differ by {worst}");
}

#[test]
fn parameter_ranges_round_trip() {
    for kind in [ModelKind::Ward, ModelKind::Ggx] {
        for r in kind.outputs() {
            for s in [0.0, 0.3, 1.0] {
                assert!((r.to_unit(r.from_unit(s)) - s).abs() < 1e-12, "{} {s}", r.name);
            }
        }
    }
    assert_eq!(ModelKind::Ward.spec(&[0.25, 0.1]), "ward:rho_d=0.2500,alpha=0.1000");
}
