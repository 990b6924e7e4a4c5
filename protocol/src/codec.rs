//! MessagePack codec: every message is encoded with `rmp_serde`'s named encoding
//! ([`try_encode_into`]), so structs are maps keyed by field name and any MessagePack reader
//! sees plain maps.

use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::error::ProtocolError;

/// The short name of `T` (module paths stripped, generics kept), for error messages.
pub fn type_label<T: ?Sized>() -> String {
    let full = std::any::type_name::<T>();
    let mut out = String::with_capacity(full.len());
    let mut segment = String::new();
    for c in full.chars() {
        match c {
            '<' | '>' | ',' | ' ' | '(' | ')' | '[' | ']' | ';' | '&' => {
                out.push_str(segment.rsplit("::").next().unwrap_or(""));
                segment.clear();
                out.push(c);
            }
            _ => segment.push(c),
        }
    }
    out.push_str(segment.rsplit("::").next().unwrap_or(""));
    out
}

/// Encodes `value` as named-map MessagePack, returning an error instead of panicking.
pub fn try_encode<T: Serialize + ?Sized>(value: &T) -> Result<Vec<u8>, ProtocolError> {
    let mut out = Vec::new();
    try_encode_into(&mut out, value)?;
    Ok(out)
}

/// [`try_encode`] appending to `out` (a buffer the caller sized, e.g. for a batch reply).
pub fn try_encode_into<T: Serialize + ?Sized>(
    out: &mut Vec<u8>,
    value: &T,
) -> Result<(), ProtocolError> {
    rmp_serde::encode::write_named(out, value).map_err(|source| ProtocolError::Encode {
        what: type_label::<T>(),
        source,
    })
}

/// Encodes `value` as named-map MessagePack.
///
/// # Panics
/// Only if `T`'s `Serialize` implementation fails, which cannot happen for this crate's
/// message types (use [`try_encode`] for arbitrary types).
pub fn encode<T: Serialize + ?Sized>(value: &T) -> Vec<u8> {
    match try_encode(value) {
        Ok(bytes) => bytes,
        Err(e) => panic!("{e}"),
    }
}

/// Decodes one message of type `T` from `bytes`. The whole input must be consumed.
/// Never panics: malformed input gives a [`ProtocolError`] naming the expected type.
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, ProtocolError> {
    let mut rest: &[u8] = bytes;
    let value = match T::deserialize(&mut rmp_serde::Deserializer::new(&mut rest)) {
        Ok(v) => v,
        // Decoded again, only on the error path, to learn where: the path names the field a
        // wrong value sits in, which rmp-serde's error does not.
        Err(first) => {
            let mut again: &[u8] = bytes;
            let mut de = rmp_serde::Deserializer::new(&mut again);
            let (path, source) = match serde_path_to_error::deserialize::<_, T>(&mut de) {
                Err(e) => (e.path().to_string(), e.into_inner()),
                Ok(_) => (String::new(), first), // decoding is deterministic: not reached
            };
            return Err(ProtocolError::Decode {
                expected: type_label::<T>(),
                path,
                source,
            });
        }
    };
    let rest = rest.len();
    if rest != 0 {
        return Err(ProtocolError::TrailingBytes {
            expected: type_label::<T>(),
            count: rest,
        });
    }
    Ok(value)
}

/// Decodes a request whose fields are all optional: an empty payload counts as an empty map.
pub fn decode_or_default<T: DeserializeOwned + Default>(bytes: &[u8]) -> Result<T, ProtocolError> {
    if bytes.is_empty() {
        Ok(T::default())
    } else {
        decode(bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_are_short() {
        assert_eq!(type_label::<crate::messages::StepResult>(), "StepResult");
        assert_eq!(
            type_label::<crate::messages::Reply<crate::messages::StepResult>>(),
            "Reply<StepResult>"
        );
    }

    #[test]
    fn trailing_bytes_rejected() {
        let mut b = encode(&crate::messages::Close {});
        b.push(0xc0);
        let e = decode::<crate::messages::Close>(&b).unwrap_err();
        assert!(
            matches!(e, ProtocolError::TrailingBytes { count: 1, .. }),
            "{e}"
        );
    }

    #[test]
    fn empty_payload_defaults() {
        let r: crate::messages::Reset = decode_or_default(&[]).unwrap();
        assert_eq!(r, crate::messages::Reset::default());
        assert!(decode::<crate::messages::Reset>(&[]).is_err());
    }
}
