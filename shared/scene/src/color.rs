//! Colour: black-body emitters and luminance.

/// Linear-sRGB colour of a black body at `kelvin`, scaled so its luminance
/// is 1 (a 6500 K body is nearly white, a 3000 K one orange).
pub fn black_body_rgb(kelvin: f32) -> [f32; 3] {
    // Integrate Planck's law against the CIE 1931 matching functions
    // (the multi-lobe Gaussian fit of Wyman, Sloan & Shirley 2013).
    let (mut x, mut y, mut z) = (0.0f64, 0.0f64, 0.0f64);
    let mut lambda = 380.0f64;
    while lambda <= 780.0 {
        let b = planck(lambda * 1e-9, kelvin as f64);
        let (xb, yb, zb) = cie_1931(lambda);
        x += b * xb;
        y += b * yb;
        z += b * zb;
        lambda += 5.0;
    }
    let (x, y, z) = (x / y, 1.0, z / y);
    // XYZ → linear sRGB (D65).
    let r = 3.2406 * x - 1.5372 * y - 0.4986 * z;
    let g = -0.9689 * x + 1.8758 * y + 0.0415 * z;
    let b = 0.0557 * x - 0.2040 * y + 1.0570 * z;
    [r, g, b].map(|c| c.max(0.0) as f32)
}

fn planck(wavelength_m: f64, kelvin: f64) -> f64 {
    const H: f64 = 6.626_070_15e-34;
    const C: f64 = 2.997_924_58e8;
    const K: f64 = 1.380_649e-23;
    2.0 * H * C * C / wavelength_m.powi(5) / ((H * C / (wavelength_m * K * kelvin)).exp() - 1.0)
}

fn cie_1931(nm: f64) -> (f64, f64, f64) {
    let g = |x: f64, mu: f64, s1: f64, s2: f64| {
        let t = (x - mu) / if x < mu { s1 } else { s2 };
        (-0.5 * t * t).exp()
    };
    let x = 1.056 * g(nm, 599.8, 37.9, 31.0) + 0.362 * g(nm, 442.0, 16.0, 26.7)
        - 0.065 * g(nm, 501.1, 20.4, 26.2);
    let y = 0.821 * g(nm, 568.8, 46.9, 40.5) + 0.286 * g(nm, 530.9, 16.3, 31.1);
    let z = 1.217 * g(nm, 437.0, 11.8, 36.0) + 0.681 * g(nm, 459.0, 26.0, 13.8);
    (x, y, z)
}

/// Rec. 709 luminance of a linear RGB colour.
pub fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// An 8-bit sRGB-encoded value as linear light in [0, 1].
pub fn srgb8_to_linear(v: u8) -> f32 {
    // A table of the formula's 256 values: the voxelizer converts three
    // texels per sample, millions of samples a model.
    static TABLE: std::sync::LazyLock<[f32; 256]> = std::sync::LazyLock::new(|| {
        std::array::from_fn(|v| {
            let c = v as f32 / 255.0;
            if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
        })
    });
    TABLE[v as usize]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn black_bodies_go_from_orange_to_white_to_blue() {
        let warm = black_body_rgb(3000.0);
        let day = black_body_rgb(6500.0);
        let cool = black_body_rgb(12000.0);
        assert!(warm[0] > warm[1] && warm[1] > warm[2]);
        // 6500 K is close to the sRGB white point.
        for c in day {
            assert!((c - 1.0).abs() < 0.12, "{day:?}");
        }
        assert!(cool[2] > cool[0]);
        assert!((luminance(day) - 1.0).abs() < 0.01);
    }
}
