//! Compact n-dimensional numeric arrays for the wire.
//!
//! On the wire an array is a MessagePack map with exactly these keys:
//!
//! ```text
//! { "dtype": "<f4" | "<f8" | "<u4" | "|u1",   // a numpy dtype string
//!   "shape": [u32, ...],                       // row-major (C order); [] = scalar
//!   "data":  bin }                             // little-endian elements, product(shape) * itemsize bytes
//! ```
//!
//! so numpy reads one without copying:
//! `np.frombuffer(m["data"], dtype=m["dtype"]).reshape(m["shape"])`.
//!
//! Decoding validates the dtype against the Rust type and the data length against the shape.

use std::fmt;
use std::marker::PhantomData;

use serde::de::{self, Deserializer, MapAccess, Visitor};
use serde::ser::{SerializeMap, Serializer};
use serde::{Deserialize, Serialize};

/// What was wrong with an array (construction, reshape or decode).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ArrayError {
    /// The data length does not match the shape.
    #[error(
        "array length mismatch: shape {shape:?} needs {expected} {dtype} elements ({expected_bytes} bytes), got {actual_bytes} bytes"
    )]
    LengthMismatch {
        dtype: &'static str,
        shape: Vec<u32>,
        expected: usize,
        expected_bytes: usize,
        actual_bytes: usize,
    },
    /// The product of the shape overflows `usize`.
    #[error("array shape {shape:?} is too large")]
    ShapeOverflow { shape: Vec<u32> },
    /// The wire dtype is not the one this field holds.
    #[error("array dtype mismatch: expected {expected}, got {actual:?}")]
    DtypeMismatch {
        expected: &'static str,
        actual: String,
    },
    /// A shape that does not fit where it is used (e.g. wrong rank or dimension).
    #[error("array has shape {actual:?}, expected {expected}")]
    WrongShape { expected: String, actual: Vec<u32> },
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for f32 {}
    impl Sealed for f64 {}
    impl Sealed for u32 {}
    impl Sealed for u64 {}
    impl Sealed for u8 {}
}

/// An element type that can be carried in an [`NdArray`].
pub trait Element: Copy + Default + PartialEq + fmt::Debug + sealed::Sealed + 'static {
    /// The numpy dtype string, e.g. `"<f4"`.
    const DTYPE: &'static str;
    /// Size of one element in bytes.
    const SIZE: usize;
    /// Appends the little-endian bytes of `self`.
    fn write_le(self, out: &mut Vec<u8>);
    /// Writes the little-endian bytes of `values` into `out` (`values.len() * SIZE` bytes).
    fn write_all_le(values: &[Self], out: &mut [u8]);
    /// Reads one element from exactly `SIZE` little-endian bytes.
    fn read_le(bytes: &[u8]) -> Self;
}

macro_rules! impl_element {
    ($t:ty, $dtype:literal, $size:literal) => {
        impl Element for $t {
            const DTYPE: &'static str = $dtype;
            const SIZE: usize = $size;
            #[inline]
            fn write_le(self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
            #[inline]
            fn write_all_le(values: &[Self], out: &mut [u8]) {
                // Indexed within slices of exactly matching lengths: this form compiles to
                // vector copies, a `chunks_exact_mut` zip to one element per iteration (5x the
                // instructions on the batch reply's arrays).
                let n = values.len().min(out.len() / $size);
                let (values, out) = (&values[..n], &mut out[..n * $size]);
                for (i, v) in values.iter().enumerate() {
                    out[i * $size..(i + 1) * $size].copy_from_slice(&v.to_le_bytes());
                }
            }
            #[inline]
            fn read_le(bytes: &[u8]) -> Self {
                let mut b = [0u8; $size];
                b.copy_from_slice(bytes);
                <$t>::from_le_bytes(b)
            }
        }
    };
}

impl_element!(f32, "<f4", 4);
impl_element!(f64, "<f8", 8);
impl_element!(u32, "<u4", 4);
impl_element!(u64, "<u8", 8);
impl_element!(u8, "|u1", 1);

/// Number of elements of `shape`, or an error on overflow.
pub fn shape_len(shape: &[u32]) -> Result<usize, ArrayError> {
    shape
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d as usize))
        .ok_or_else(|| ArrayError::ShapeOverflow {
            shape: shape.to_vec(),
        })
}

/// Elements and bytes of an array of `T` of `shape`, or an error on overflow.
fn shape_bytes<T: Element>(shape: &[u32]) -> Result<(usize, usize), ArrayError> {
    let n = shape_len(shape)?;
    let bytes = n
        .checked_mul(T::SIZE)
        .ok_or_else(|| ArrayError::ShapeOverflow {
            shape: shape.to_vec(),
        })?;
    Ok((n, bytes))
}

/// The number of elements of `shape`, or an error unless `len` values fill it exactly.
fn checked_len<T: Element>(shape: &[u32], len: usize) -> Result<usize, ArrayError> {
    let n = shape_len(shape)?;
    if len != n {
        return Err(ArrayError::LengthMismatch {
            dtype: T::DTYPE,
            shape: shape.to_vec(),
            expected: n,
            expected_bytes: n.saturating_mul(T::SIZE),
            actual_bytes: len.saturating_mul(T::SIZE),
        });
    }
    Ok(n)
}

/// A row-major n-dimensional array of `T`, stored as little-endian bytes.
#[derive(Clone, PartialEq)]
pub struct NdArray<T: Element> {
    shape: Vec<u32>,
    data: Vec<u8>,
    _elem: PhantomData<T>,
}

/// `<f4` array.
pub type F32Array = NdArray<f32>;
/// `<f8` array.
pub type F64Array = NdArray<f64>;
/// `<u4` array.
pub type U32Array = NdArray<u32>;
/// `<u8` array.
pub type U64Array = NdArray<u64>;
/// `|u1` array (also used for booleans: 0 = false, 1 = true).
pub type U8Array = NdArray<u8>;

impl<T: Element> NdArray<T> {
    /// Builds an array from row-major values; errors unless `values.len() == product(shape)`.
    pub fn new(shape: Vec<u32>, values: &[T]) -> Result<Self, ArrayError> {
        let n = checked_len::<T>(&shape, values.len())?;
        let mut data = vec![0u8; n * T::SIZE];
        T::write_all_le(values, &mut data);
        Ok(Self {
            shape,
            data,
            _elem: PhantomData,
        })
    }

    /// Builds a 1-D array of `values.len()` elements.
    pub fn from_slice(values: &[T]) -> Self {
        let len = u32::try_from(values.len()).expect("array longer than u32::MAX elements");
        Self::new(vec![len], values).expect("1-D shape always matches")
    }

    /// Builds an array from raw little-endian bytes; errors unless the byte length matches the shape.
    pub fn from_le_bytes(shape: Vec<u32>, data: Vec<u8>) -> Result<Self, ArrayError> {
        let (n, expected_bytes) = shape_bytes::<T>(&shape)?;
        if data.len() != expected_bytes {
            return Err(ArrayError::LengthMismatch {
                dtype: T::DTYPE,
                shape,
                expected: n,
                expected_bytes,
                actual_bytes: data.len(),
            });
        }
        Ok(Self {
            shape,
            data,
            _elem: PhantomData,
        })
    }

    /// An array of the given shape filled with zeros.
    pub fn zeros(shape: Vec<u32>) -> Result<Self, ArrayError> {
        let (_, bytes) = shape_bytes::<T>(&shape)?;
        Ok(Self {
            shape,
            data: vec![0u8; bytes],
            _elem: PhantomData,
        })
    }

    /// The numpy dtype string of this array type.
    pub fn dtype(&self) -> &'static str {
        T::DTYPE
    }

    /// The shape (row-major).
    pub fn shape(&self) -> &[u32] {
        &self.shape
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.data.len() / T::SIZE
    }

    /// Whether the array has no elements.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// The raw little-endian bytes.
    pub fn as_le_bytes(&self) -> &[u8] {
        &self.data
    }

    /// Consumes the array, returning `(shape, little-endian bytes)`.
    pub fn into_parts(self) -> (Vec<u32>, Vec<u8>) {
        (self.shape, self.data)
    }

    /// The element at flat (row-major) index `i`.
    pub fn get_flat(&self, i: usize) -> Option<T> {
        let start = i.checked_mul(T::SIZE)?;
        self.data.get(start..start + T::SIZE).map(T::read_le)
    }

    /// The element at a multi-dimensional index, or `None` if out of bounds / wrong rank.
    pub fn get(&self, index: &[u32]) -> Option<T> {
        if index.len() != self.shape.len() {
            return None;
        }
        let mut flat = 0usize;
        for (&i, &d) in index.iter().zip(&self.shape) {
            if i >= d {
                return None;
            }
            flat = flat * d as usize + i as usize;
        }
        self.get_flat(flat)
    }

    /// Iterates over the elements in row-major order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = T> + '_ {
        self.data.chunks_exact(T::SIZE).map(T::read_le)
    }

    /// All elements in row-major order.
    pub fn to_vec(&self) -> Vec<T> {
        self.iter().collect()
    }

    /// Returns the same data with a new shape of equal element count.
    pub fn reshape(self, shape: Vec<u32>) -> Result<Self, ArrayError> {
        Self::from_le_bytes(shape, self.data)
    }

    /// Errors with [`ArrayError::WrongShape`] unless the shape equals `expected`
    /// (a `None` entry matches any size).
    pub fn check_shape(&self, expected: &[Option<u32>]) -> Result<(), ArrayError> {
        let ok = self.shape.len() == expected.len()
            && self.shape.iter().zip(expected).all(|(&d, e)| match e {
                Some(e) => *e == d,
                None => true,
            });
        if ok {
            Ok(())
        } else {
            let dims: Vec<String> = expected
                .iter()
                .map(|e| e.map_or_else(|| "*".to_string(), |d| d.to_string()))
                .collect();
            Err(ArrayError::WrongShape {
                expected: format!("[{}]", dims.join(", ")),
                actual: self.shape.clone(),
            })
        }
    }

    /// Stacks arrays of equal shape along a new leading axis.
    pub fn stack(parts: &[Self]) -> Result<Self, ArrayError> {
        let inner = parts.first().map_or_else(Vec::new, |p| p.shape.clone());
        let mut data = Vec::with_capacity(parts.iter().map(|p| p.data.len()).sum());
        for p in parts {
            if p.shape != inner {
                return Err(ArrayError::WrongShape {
                    expected: format!("{inner:?}"),
                    actual: p.shape.clone(),
                });
            }
            data.extend_from_slice(&p.data);
        }
        let k = u32::try_from(parts.len()).map_err(|_| ArrayError::ShapeOverflow {
            shape: inner.clone(),
        })?;
        let mut shape = Vec::with_capacity(inner.len() + 1);
        shape.push(k);
        shape.extend_from_slice(&inner);
        Self::from_le_bytes(shape, data)
    }
}

impl<T: Element> fmt::Debug for NdArray<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("NdArray")
            .field("dtype", &T::DTYPE)
            .field("shape", &self.shape)
            .field("data", &self.to_vec())
            .finish()
    }
}

impl<T: Element> Serialize for NdArray<T> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serialize_wire_array(serializer, T::DTYPE, &self.shape, &self.data)
    }
}

/// The wire layout of every array: `{dtype, shape, data}` with `data` as bin.
fn serialize_wire_array<S: Serializer>(
    serializer: S,
    dtype: &str,
    shape: &[u32],
    data: &[u8],
) -> Result<S::Ok, S::Error> {
    let mut m = serializer.serialize_map(Some(3))?;
    m.serialize_entry("dtype", dtype)?;
    m.serialize_entry("shape", shape)?;
    m.serialize_entry("data", serde_bytes::Bytes::new(data))?;
    m.end()
}

/// A row-major array borrowed from the caller's buffer: it serializes to exactly the bytes of
/// the [`NdArray`] with the same shape and values, without building that array (on a
/// little-endian host the values go out as they lie in memory).
#[derive(Debug, Clone)]
pub struct ArrayView<'a, T: Element> {
    shape: Vec<u32>,
    values: &'a [T],
}

impl<'a, T: Element> ArrayView<'a, T> {
    /// A view of `values` (row-major) as an array of `shape`.
    pub fn new(shape: Vec<u32>, values: &'a [T]) -> Result<Self, ArrayError> {
        let n = checked_len::<T>(&shape, values.len())?;
        // MessagePack's bin holds at most 2^32 - 1 bytes.
        if n.checked_mul(T::SIZE)
            .is_none_or(|b| u32::try_from(b).is_err())
        {
            return Err(ArrayError::ShapeOverflow { shape });
        }
        Ok(Self { shape, values })
    }
}

impl<T: Element> Serialize for ArrayView<'_, T> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serialize_wire_array(serializer, T::DTYPE, &self.shape, &le_bytes(self.values))
    }
}

/// The little-endian bytes of `values`: borrowed on a little-endian host, copied otherwise.
fn le_bytes<T: Element>(values: &[T]) -> std::borrow::Cow<'_, [u8]> {
    if cfg!(target_endian = "little") {
        // SAFETY: `T` is one of f32, f64, u32, u64, u8 (the trait is sealed): no padding and
        // every byte initialised, so its memory may be read as bytes; `size_of_val` bytes from
        // the slice's start stay inside it; `u8` needs no alignment. On a little-endian host
        // those bytes are the little-endian encoding.
        std::borrow::Cow::Borrowed(unsafe {
            std::slice::from_raw_parts(values.as_ptr().cast::<u8>(), std::mem::size_of_val(values))
        })
    } else {
        let mut bytes = vec![0; values.len() * T::SIZE];
        T::write_all_le(values, &mut bytes);
        std::borrow::Cow::Owned(bytes)
    }
}

/// The three wire fields before validation.
#[derive(Default)]
struct RawArray {
    dtype: Option<String>,
    shape: Option<Vec<u32>>,
    data: Option<Vec<u8>>,
}

/// A MessagePack `bin` value and nothing else (no str, no array of ints).
struct StrictBytes(Vec<u8>);

impl<'de> Deserialize<'de> for StrictBytes {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = StrictBytes;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("MessagePack bin data")
            }
            fn visit_bytes<E: de::Error>(self, v: &[u8]) -> Result<StrictBytes, E> {
                Ok(StrictBytes(v.to_vec()))
            }
            fn visit_byte_buf<E: de::Error>(self, v: Vec<u8>) -> Result<StrictBytes, E> {
                Ok(StrictBytes(v))
            }
        }
        deserializer.deserialize_byte_buf(V)
    }
}

struct RawArrayVisitor;

impl<'de> Visitor<'de> for RawArrayVisitor {
    type Value = RawArray;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("an array map {dtype, shape, data}")
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<RawArray, A::Error> {
        let mut raw = RawArray::default();
        while let Some(key) = map.next_key::<String>()? {
            match key.as_str() {
                "dtype" => {
                    if raw.dtype.is_some() {
                        return Err(de::Error::duplicate_field("dtype"));
                    }
                    raw.dtype = Some(map.next_value()?);
                }
                "shape" => {
                    if raw.shape.is_some() {
                        return Err(de::Error::duplicate_field("shape"));
                    }
                    raw.shape = Some(map.next_value()?);
                }
                "data" => {
                    if raw.data.is_some() {
                        return Err(de::Error::duplicate_field("data"));
                    }
                    raw.data = Some(map.next_value::<StrictBytes>()?.0);
                }
                _ => {
                    map.next_value::<de::IgnoredAny>()?;
                }
            }
        }
        Ok(raw)
    }
}

impl RawArray {
    fn parse<'de, D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        deserializer.deserialize_map(RawArrayVisitor)
    }

    fn dtype<E: de::Error>(&self) -> Result<&str, E> {
        self.dtype
            .as_deref()
            .ok_or_else(|| de::Error::missing_field("dtype"))
    }

    fn into_array<T: Element, E: de::Error>(self) -> Result<NdArray<T>, E> {
        let dtype = self.dtype::<E>()?;
        if dtype != T::DTYPE {
            return Err(de::Error::custom(ArrayError::DtypeMismatch {
                expected: T::DTYPE,
                actual: dtype.to_string(),
            }));
        }
        let shape = self
            .shape
            .ok_or_else(|| de::Error::missing_field("shape"))?;
        let data = self.data.ok_or_else(|| de::Error::missing_field("data"))?;
        NdArray::from_le_bytes(shape, data).map_err(de::Error::custom)
    }
}

impl<'de, T: Element> Deserialize<'de> for NdArray<T> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        RawArray::parse(deserializer)?.into_array()
    }
}

/// A float array whose dtype is chosen by the sender: `<f4` or `<f8`.
/// Used for actions, so numpy senders need not convert `float64` to `float32`.
#[derive(Debug, Clone, PartialEq)]
pub enum FloatArray {
    /// `<f4` data.
    F32(F32Array),
    /// `<f8` data.
    F64(F64Array),
}

impl FloatArray {
    /// The shape.
    pub fn shape(&self) -> &[u32] {
        match self {
            FloatArray::F32(a) => a.shape(),
            FloatArray::F64(a) => a.shape(),
        }
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        match self {
            FloatArray::F32(a) => a.len(),
            FloatArray::F64(a) => a.len(),
        }
    }

    /// Whether the array has no elements.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// All elements converted to `f64`, row-major.
    pub fn to_f64_vec(&self) -> Vec<f64> {
        match self {
            FloatArray::F32(a) => a.iter().map(f64::from).collect(),
            FloatArray::F64(a) => a.to_vec(),
        }
    }

    /// Same as [`NdArray::check_shape`].
    pub fn check_shape(&self, expected: &[Option<u32>]) -> Result<(), ArrayError> {
        match self {
            FloatArray::F32(a) => a.check_shape(expected),
            FloatArray::F64(a) => a.check_shape(expected),
        }
    }
}

impl From<F32Array> for FloatArray {
    fn from(a: F32Array) -> Self {
        FloatArray::F32(a)
    }
}

impl From<F64Array> for FloatArray {
    fn from(a: F64Array) -> Self {
        FloatArray::F64(a)
    }
}

impl Serialize for FloatArray {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            FloatArray::F32(a) => a.serialize(serializer),
            FloatArray::F64(a) => a.serialize(serializer),
        }
    }
}

impl<'de> Deserialize<'de> for FloatArray {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let raw = RawArray::parse(deserializer)?;
        match raw.dtype::<D::Error>()? {
            "<f4" => raw.into_array().map(FloatArray::F32),
            "<f8" => raw.into_array().map(FloatArray::F64),
            other => Err(de::Error::custom(ArrayError::DtypeMismatch {
                expected: "<f4 or <f8",
                actual: other.to_string(),
            })),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn construct_and_read_back() {
        let a = F32Array::new(vec![2, 3], &[0.0, 1.0, 2.0, 3.0, 4.0, 5.0]).unwrap();
        assert_eq!(a.len(), 6);
        assert_eq!(a.get(&[1, 2]), Some(5.0));
        assert_eq!(a.get(&[2, 0]), None);
        assert_eq!(a.get(&[0]), None);
        assert_eq!(a.as_le_bytes()[4..8], 1.0f32.to_le_bytes());
        assert_eq!(a.to_vec(), vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
        let b = a.clone().reshape(vec![3, 2]).unwrap();
        assert_eq!(b.shape(), &[3, 2]);
        assert!(a.clone().reshape(vec![4]).is_err());
        assert!(a.check_shape(&[Some(2), None]).is_ok());
        assert!(matches!(
            a.check_shape(&[Some(3), None]),
            Err(ArrayError::WrongShape { .. })
        ));
    }

    #[test]
    fn length_mismatch_errors() {
        let e = F64Array::new(vec![2, 2], &[1.0, 2.0, 3.0]).unwrap_err();
        assert!(matches!(
            e,
            ArrayError::LengthMismatch {
                expected: 4,
                actual_bytes: 24,
                ..
            }
        ));
        assert!(U32Array::from_le_bytes(vec![3], vec![0; 11]).is_err());
        assert!(U8Array::from_le_bytes(vec![u32::MAX, u32::MAX, u32::MAX], vec![]).is_err());
    }

    #[test]
    fn scalar_and_empty() {
        let s = F64Array::new(vec![], &[7.5]).unwrap();
        assert_eq!(s.len(), 1);
        assert_eq!(s.get(&[]), Some(7.5));
        let e = F32Array::new(vec![0, 11], &[]).unwrap();
        assert!(e.is_empty());
    }

    #[test]
    fn stack_along_new_axis() {
        let a = U8Array::from_slice(&[1, 0]);
        let b = U8Array::from_slice(&[0, 1]);
        let s = U8Array::stack(&[a.clone(), b]).unwrap();
        assert_eq!(s.shape(), &[2, 2]);
        assert_eq!(s.to_vec(), vec![1, 0, 0, 1]);
        assert!(U8Array::stack(&[a, U8Array::from_slice(&[1])]).is_err());
        assert_eq!(F32Array::stack(&[]).unwrap().shape(), &[0]);
    }
}
