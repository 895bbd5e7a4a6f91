//! Grids on disk as NumPy `.npy` files: float32, C order, shape
//! `(Z, Y, X)` for one grid and `(C, Z, Y, X)` for per-channel results.

use crate::lb::{GridDims, MediumGrid, NodeClass};
use crate::{Error, Result};
use npyz::WriterBuilder;
use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::Path;

/// Reads a density grid: float32, shape `(Z, Y, X)`, values in [0, 1];
/// every node gets `class`.
pub fn read_density(path: &Path, class: NodeClass) -> Result<MediumGrid> {
    let file_error = |what, error| Error::File { path: path.to_path_buf(), what, error };
    let format_error = |message| Error::Format { path: path.to_path_buf(), message };
    let file = File::open(path).map_err(|e| file_error("cannot open", e))?;
    let npy =
        npyz::NpyFile::new(BufReader::new(file)).map_err(|e| file_error("not a .npy file", e))?;
    let shape = npy.shape().to_vec();
    if shape.len() != 3 {
        return Err(format_error(format!("density grid must have shape (Z, Y, X), got {shape:?}")));
    }
    if npy.order() != npyz::Order::C {
        return Err(format_error(
            "density grid must be in C order (numpy's default), not Fortran order".into(),
        ));
    }
    let dtype = npy.dtype();
    let is_f32 = matches!(&dtype, npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Float && t.size_field() == 4);
    if !is_f32 {
        return Err(format_error(format!("density grid must be float32, got {}", dtype.descr())));
    }
    let dims = GridDims { nz: shape[0] as usize, ny: shape[1] as usize, nx: shape[2] as usize };
    let density: Vec<f32> =
        npy.into_vec().map_err(|e| file_error("truncated or unreadable data", e))?;
    let medium = MediumGrid { dims, class: vec![class; density.len()], density };
    medium.validate().map_err(|error| Error::Density { path: path.to_path_buf(), error })?;
    Ok(medium)
}

/// Writes a float32 `.npy` array of `shape` (C order).
pub fn write_f32(path: &Path, shape: &[u64], data: &[f32]) -> Result<()> {
    let expected: u64 = shape.iter().product();
    if expected != data.len() as u64 {
        return Err(Error::Invalid(format!(
            "shape {shape:?} needs {expected} values, got {}",
            data.len()
        )));
    }
    let file = File::create(path).map_err(|error| Error::File {
        path: path.to_path_buf(),
        what: "cannot create",
        error,
    })?;
    let mut w = npyz::WriteOptions::<f32>::new()
        .default_dtype()
        .shape(shape)
        .writer(BufWriter::new(file))
        .begin_nd()?;
    w.extend(data.iter().copied())?;
    w.finish()?;
    Ok(())
}

/// Writes a density grid as `(Z, Y, X)`.
pub fn write_density(path: &Path, medium: &MediumGrid) -> Result<()> {
    let d = medium.dims;
    write_f32(path, &[d.nz as u64, d.ny as u64, d.nx as u64], &medium.density)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn density_round_trips_and_bad_values_are_refused() {
        let dir = std::env::temp_dir().join(format!("sylva-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let dims = GridDims { nx: 5, ny: 4, nz: 3 };
        let mut m = MediumGrid::empty(dims);
        m.density[dims.index(2, 1, 1)] = 0.5;
        let p = dir.join("d.npy");
        write_density(&p, &m).unwrap();
        let back = read_density(&p, NodeClass::Medium).unwrap();
        assert_eq!(back, m);

        m.density[0] = 1.5;
        write_density(&p, &m).unwrap();
        let err = format!("{:#}", read_density(&p, NodeClass::Medium).unwrap_err());
        assert!(err.contains("density at node (x=0, y=0, z=0) is 1.5"), "{err}");

        write_f32(&p, &[2, 10], &[0.0; 20]).unwrap();
        let err = format!("{:#}", read_density(&p, NodeClass::Medium).unwrap_err());
        assert!(err.contains("shape (Z, Y, X)"), "{err}");

        std::fs::write(&p, b"not numpy").unwrap();
        assert!(
            format!("{:#}", read_density(&p, NodeClass::Medium).unwrap_err())
                .contains("not a .npy")
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
