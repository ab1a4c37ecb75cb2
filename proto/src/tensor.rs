//! Packing slices into `Tensor` messages and reading them back without copies where possible.

use std::borrow::Cow;

use bytes::Bytes;
use thiserror::Error;

use crate::v1::{Dtype, Tensor};

/// A tensor that does not hold what its header says.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum TensorError {
    /// The dtype is not the one expected.
    #[error("tensor `{name}` has dtype {got:?}, expected {expected:?}")]
    Dtype {
        /// Tensor name.
        name: String,
        /// Declared dtype.
        got: Dtype,
        /// Expected dtype.
        expected: Dtype,
    },
    /// The byte length does not match the shape.
    #[error("tensor `{name}` has {bytes} bytes, but its shape {shape:?} needs {needed}")]
    Length {
        /// Tensor name.
        name: String,
        /// Declared shape.
        shape: Vec<u32>,
        /// Bytes present.
        bytes: usize,
        /// Bytes the shape needs.
        needed: usize,
    },
    /// The shape is not the one expected.
    #[error("tensor `{name}` has shape {got:?}, expected {expected:?}")]
    Shape {
        /// Tensor name.
        name: String,
        /// Declared shape.
        got: Vec<u32>,
        /// Expected shape.
        expected: Vec<u32>,
    },
}

fn pack<T: bytemuck::Pod>(values: &[T], shape: &[usize], dtype: Dtype) -> Tensor {
    // The wire format is little-endian, which is the in-memory layout on every platform we
    // build for; a big-endian target would need a byte swap here.
    #[cfg(target_endian = "big")]
    compile_error!("unigait's tensor packing assumes a little-endian target");
    Tensor {
        shape: shape.iter().map(|&d| d as u32).collect(),
        dtype: dtype as i32,
        data: Bytes::copy_from_slice(bytemuck::cast_slice(values)),
    }
}

/// An f32 tensor of `shape` holding `values`.
pub fn f32_tensor(values: &[f32], shape: &[usize]) -> Tensor {
    pack(values, shape, Dtype::F32)
}

/// A u8 tensor.
pub fn u8_tensor(values: &[u8], shape: &[usize]) -> Tensor {
    pack(values, shape, Dtype::U8)
}

/// A u32 tensor.
pub fn u32_tensor(values: &[u32], shape: &[usize]) -> Tensor {
    pack(values, shape, Dtype::U32)
}

/// Checked read access to a received tensor.
pub trait TensorView {
    /// The values as f32, borrowed when the buffer is aligned, copied otherwise.
    fn f32_values(&self, name: &str) -> Result<Cow<'_, [f32]>, TensorError>;
    /// The values as u8.
    fn u8_values(&self, name: &str) -> Result<&[u8], TensorError>;
    /// The values as u32 (borrowed when aligned).
    fn u32_values(&self, name: &str) -> Result<Cow<'_, [u32]>, TensorError>;
    /// Fail unless the shape equals `expected`.
    fn expect_shape(&self, name: &str, expected: &[usize]) -> Result<(), TensorError>;
}

fn checked<'a>(
    t: &'a Tensor,
    name: &str,
    dtype: Dtype,
    size: usize,
) -> Result<&'a [u8], TensorError> {
    let got = Dtype::try_from(t.dtype).unwrap_or(Dtype::Unspecified);
    if got != dtype {
        return Err(TensorError::Dtype {
            name: name.into(),
            got,
            expected: dtype,
        });
    }
    let count: usize = t.shape.iter().map(|&d| d as usize).product();
    let needed = count * size;
    if t.data.len() != needed {
        return Err(TensorError::Length {
            name: name.into(),
            shape: t.shape.clone(),
            bytes: t.data.len(),
            needed,
        });
    }
    Ok(&t.data)
}

fn cast<T: bytemuck::Pod>(bytes: &[u8]) -> Cow<'_, [T]> {
    match bytemuck::try_cast_slice(bytes) {
        Ok(values) => Cow::Borrowed(values),
        Err(_) => Cow::Owned(
            bytes
                .chunks_exact(size_of::<T>())
                .map(bytemuck::pod_read_unaligned)
                .collect(),
        ),
    }
}

impl TensorView for Tensor {
    fn f32_values(&self, name: &str) -> Result<Cow<'_, [f32]>, TensorError> {
        checked(self, name, Dtype::F32, 4).map(cast)
    }

    fn u8_values(&self, name: &str) -> Result<&[u8], TensorError> {
        checked(self, name, Dtype::U8, 1)
    }

    fn u32_values(&self, name: &str) -> Result<Cow<'_, [u32]>, TensorError> {
        checked(self, name, Dtype::U32, 4).map(cast)
    }

    fn expect_shape(&self, name: &str, expected: &[usize]) -> Result<(), TensorError> {
        if self.shape.len() != expected.len()
            || self
                .shape
                .iter()
                .zip(expected)
                .any(|(a, b)| *a as usize != *b)
        {
            return Err(TensorError::Shape {
                name: name.into(),
                got: self.shape.clone(),
                expected: expected.iter().map(|&d| d as u32).collect(),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod test {
    use super::*;

    #[test]
    fn round_trip_and_checks() {
        let t = f32_tensor(&[1.0, -2.5, 3.0, 4.0], &[2, 2]);
        assert_eq!(t.data.len(), 16);
        assert_eq!(&t.data[4..8], &(-2.5f32).to_le_bytes());
        assert_eq!(t.f32_values("x").unwrap().as_ref(), &[1.0, -2.5, 3.0, 4.0]);
        assert!(t.expect_shape("x", &[2, 2]).is_ok());
        assert!(matches!(
            t.expect_shape("x", &[4]),
            Err(TensorError::Shape { .. })
        ));
        assert!(matches!(t.u8_values("x"), Err(TensorError::Dtype { .. })));
        let mut short = t.clone();
        short.data = short.data.slice(0..12);
        assert!(matches!(
            short.f32_values("x"),
            Err(TensorError::Length { needed: 16, .. })
        ));
        // An unaligned buffer is copied, not misread.
        let raw: Vec<u8> = [0u8].iter().chain(t.data.iter()).copied().collect();
        let mut unaligned = t.clone();
        unaligned.data = Bytes::from(raw).slice(1..);
        assert_eq!(
            unaligned.f32_values("x").unwrap().as_ref(),
            &[1.0, -2.5, 3.0, 4.0]
        );
    }
}
