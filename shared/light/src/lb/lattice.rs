//! The D3Q19 lattice: direction 0 is rest, 1–6 axial, 7–18 the edge diagonals.

/// Number of lattice directions.
pub const Q: usize = 19;

/// Lattice velocities `c_m` in the order of the design: rest, ±x, ±y, ±z,
/// then the twelve edge diagonals.
pub const DIRECTIONS: [[i32; 3]; Q] = [
    [0, 0, 0],
    [1, 0, 0],
    [-1, 0, 0],
    [0, 1, 0],
    [0, -1, 0],
    [0, 0, 1],
    [0, 0, -1],
    [1, 1, 0],
    [-1, -1, 0],
    [1, -1, 0],
    [-1, 1, 0],
    [1, 0, 1],
    [-1, 0, -1],
    [1, 0, -1],
    [-1, 0, 1],
    [0, 1, 1],
    [0, -1, -1],
    [0, 1, -1],
    [0, -1, 1],
];

/// Whether direction `m` is axial (1–6); the rest direction is neither.
pub fn is_axial(m: usize) -> bool {
    (1..=6).contains(&m)
}

/// The scattering weight denominator of direction `m > 0`: 12 axial, 24 diagonal.
pub fn weight_denominator(m: usize) -> f64 {
    debug_assert!(m > 0);
    if is_axial(m) { 12.0 } else { 24.0 }
}

/// Unit vector along `c_m` (`m > 0`).
pub fn unit(m: usize) -> [f64; 3] {
    let c = DIRECTIONS[m];
    let len = ((c[0] * c[0] + c[1] * c[1] + c[2] * c[2]) as f64).sqrt();
    [c[0] as f64 / len, c[1] as f64 / len, c[2] as f64 / len]
}

/// Index of the direction opposite `m`.
pub fn opposite(m: usize) -> usize {
    let c = DIRECTIONS[m];
    DIRECTIONS
        .iter()
        .position(|d| d[0] == -c[0] && d[1] == -c[1] && d[2] == -c[2])
        .expect("D3Q19 is symmetric")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directions_are_distinct_and_symmetric() {
        for m in 0..Q {
            assert_eq!(opposite(opposite(m)), m);
            for n in 0..m {
                assert_ne!(DIRECTIONS[m], DIRECTIONS[n]);
            }
        }
        for m in 1..=6 {
            let c = DIRECTIONS[m];
            assert_eq!(c.iter().map(|v| v.abs()).sum::<i32>(), 1);
        }
        for m in 7..Q {
            let c = DIRECTIONS[m];
            assert_eq!(c.iter().map(|v| v.abs()).sum::<i32>(), 2);
        }
    }
}
