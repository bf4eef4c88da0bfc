//! Artifact encoding: the only place bincode is used (DEVELOPERS.md, design card).
//!
//! Layout: 8-byte magic, u32 format version, u32 reserved, u64 payload length, 32-byte blake3 of
//! the payload, payload (bincode 2, standard config, through serde). `decode` verifies everything
//! before deserializing, so a truncated or bit-flipped artifact is reported, never used.
use serde::{de::DeserializeOwned, Serialize};

pub const MAGIC: [u8; 8] = *b"BVHLAB\x00A";
/// Bump when the header or bincode configuration changes.
pub const FORMAT_VERSION: u32 = 1;
pub const HEADER_LEN: usize = 8 + 4 + 4 + 8 + 32;

fn config() -> bincode::config::Configuration {
    bincode::config::standard()
}

pub fn encode<T: Serialize>(value: &T) -> Result<Vec<u8>, String> {
    let (header, payload) = encode_parts(value)?;
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
    out.extend_from_slice(&header);
    out.extend_from_slice(&payload);
    Ok(out)
}

/// blake3 of `value`'s encoding, streamed through a 16 KiB buffer instead of built in memory: the
/// timed stages check every call's result with it inside their peak-heap window (`crate::batch`).
/// Not the artifact's file hash (no header), only equal for equal values.
pub fn digest<T: Serialize>(value: &T) -> Result<blake3::Hash, String> {
    let mut w = std::io::BufWriter::with_capacity(1 << 14, blake3::Hasher::new());
    bincode::serde::encode_into_std_write(value, &mut w, config()).map_err(|e| format!("encode: {e}"))?;
    let h = w.into_inner().map_err(|e| format!("encode: {e}"))?;
    Ok(h.finalize())
}

/// Header and payload separately (the store writes them one after the other, so a large artifact
/// is not copied a second time in memory). `header ++ payload == encode(value)`.
///
/// The header does not name the artifact's stage or key: that binding is the manifest's job (it
/// records the blake3 of the whole file and is itself checked against its stage and key, see
/// `Store::get_entry`), so the format, and every existing cache, stays as it is.
pub fn encode_parts<T: Serialize>(value: &T) -> Result<([u8; HEADER_LEN], Vec<u8>), String> {
    let payload =
        bincode::serde::encode_to_vec(value, config()).map_err(|e| format!("encode: {e}"))?;
    let mut header = [0u8; HEADER_LEN];
    header[0..8].copy_from_slice(&MAGIC);
    header[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
    header[16..24].copy_from_slice(&(payload.len() as u64).to_le_bytes());
    header[24..56].copy_from_slice(blake3::hash(&payload).as_bytes());
    Ok((header, payload))
}

/// Checks header, length and checksum; returns the payload slice.
pub fn verify(bytes: &[u8]) -> Result<&[u8], String> {
    if bytes.len() < HEADER_LEN {
        return Err(format!(
            "truncated: {} bytes, header needs {HEADER_LEN}",
            bytes.len()
        ));
    }
    if bytes[0..8] != MAGIC {
        return Err("bad magic (not a bvhlab artifact)".into());
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap());
    if version != FORMAT_VERSION {
        return Err(format!(
            "format version {version}, expected {FORMAT_VERSION}"
        ));
    }
    let len = u64::from_le_bytes(bytes[16..24].try_into().unwrap());
    let payload = &bytes[HEADER_LEN..];
    if payload.len() as u64 != len {
        return Err(format!(
            "payload is {} bytes, header says {len}",
            payload.len()
        ));
    }
    if blake3::hash(payload).as_bytes() != &bytes[24..56] {
        return Err("blake3 checksum mismatch".into());
    }
    Ok(payload)
}

pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, String> {
    let payload = verify(bytes)?;
    let (value, used): (T, usize) =
        bincode::serde::decode_from_slice(payload, config()).map_err(|e| format!("decode: {e}"))?;
    if used != payload.len() {
        return Err(format!("decode: {} trailing bytes", payload.len() - used));
    }
    Ok(value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
    struct T {
        a: u64,
        b: Vec<f32>,
        s: String,
    }

    fn sample() -> T {
        T {
            a: 7,
            b: vec![1.5, -0.0, f32::INFINITY],
            s: "hi".into(),
        }
    }

    #[test]
    fn round_trip() {
        let bytes = encode(&sample()).unwrap();
        let back: T = decode(&bytes).unwrap();
        assert_eq!(back, sample());
    }

    #[test]
    fn digest_is_the_payload_hash_and_tells_values_apart() {
        let (_, payload) = encode_parts(&sample()).unwrap();
        assert_eq!(digest(&sample()).unwrap(), blake3::hash(&payload));
        let mut other = sample();
        other.b[1] = 0.0;
        assert_ne!(digest(&other).unwrap(), digest(&sample()).unwrap(), "-0.0 and 0.0 differ in bits");
        // Longer than the 16 KiB buffer.
        let big = T { a: 1, b: vec![0.25; 10_000], s: String::new() };
        assert_eq!(digest(&big).unwrap(), blake3::hash(&encode_parts(&big).unwrap().1));
    }

    #[test]
    fn every_flipped_byte_is_detected() {
        let bytes = encode(&sample()).unwrap();
        for i in 0..bytes.len() {
            let mut b = bytes.clone();
            b[i] ^= 0x40;
            // Byte 12..16 is reserved and not checked; everything else must be.
            if (12..16).contains(&i) {
                continue;
            }
            assert!(decode::<T>(&b).is_err(), "flip at {i} not detected");
        }
    }

    #[test]
    fn truncation_and_extension_are_detected() {
        let bytes = encode(&sample()).unwrap();
        assert!(decode::<T>(&bytes[..bytes.len() - 1]).is_err());
        assert!(decode::<T>(&bytes[..10]).is_err());
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(decode::<T>(&longer).is_err());
    }

    #[test]
    fn wrong_type_is_an_error_not_a_panic() {
        let bytes = encode(&"a string".to_string()).unwrap();
        assert!(decode::<T>(&bytes).is_err());
    }
}
