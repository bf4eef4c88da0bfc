//! Stage keys: blake3 over a canonical, length-prefixed encoding of (stage name, stage version,
//! parameters sorted by name, input keys in order). Parameters are canonical strings, defaults
//! included, so `bins=16` given or defaulted yields the same key.
use std::collections::BTreeMap;
use std::fmt;

#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Key(pub [u8; 32]);

impl Key {
    pub fn hex(&self) -> String {
        self.0.iter().map(|b| format!("{b:02x}")).collect()
    }
    pub fn from_hex(s: &str) -> Option<Key> {
        if s.len() != 64 {
            return None;
        }
        let mut out = [0u8; 32];
        for (i, o) in out.iter_mut().enumerate() {
            *o = u8::from_str_radix(s.get(2 * i..2 * i + 2)?, 16).ok()?;
        }
        Some(Key(out))
    }
}

impl fmt::Debug for Key {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Key({})", &self.hex()[..16])
    }
}

impl fmt::Display for Key {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.hex())
    }
}

fn put_str(h: &mut blake3::Hasher, s: &str) {
    h.update(&(s.len() as u64).to_le_bytes());
    h.update(s.as_bytes());
}

pub fn stage_key(
    stage: &str,
    version: u32,
    params: &BTreeMap<String, String>,
    inputs: &[Key],
) -> Key {
    let mut h = blake3::Hasher::new();
    h.update(b"bvhlab-stage-key-v1\0");
    put_str(&mut h, stage);
    h.update(&version.to_le_bytes());
    h.update(&(params.len() as u64).to_le_bytes());
    for (k, v) in params {
        put_str(&mut h, k);
        put_str(&mut h, v);
    }
    h.update(&(inputs.len() as u64).to_le_bytes());
    for k in inputs {
        h.update(&k.0);
    }
    Key(*h.finalize().as_bytes())
}

/// `k=v` joined by `,` in key order.
pub fn params_string(params: &BTreeMap<String, String>) -> String {
    params
        .iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect::<Vec<_>>()
        .join(",")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(kv: &[(&str, &str)]) -> BTreeMap<String, String> {
        kv.iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn key_depends_on_every_part() {
        let key = |stage: &str, version: u32, bins: &str, input: &[Key]| {
            stage_key(stage, version, &p(&[("bins", bins)]), input)
        };
        let base = key("build", 1, "16", &[Key([1; 32])]);
        assert_eq!(base, key("build", 1, "16", &[Key([1; 32])]));
        assert_ne!(base, key("compact", 1, "16", &[Key([1; 32])]));
        assert_ne!(base, key("build", 2, "16", &[Key([1; 32])]));
        assert_ne!(base, key("build", 1, "8", &[Key([1; 32])]));
        assert_ne!(base, key("build", 1, "16", &[Key([2; 32])]));
        assert_ne!(base, stage_key("build", 1, &p(&[("bins", "16")]), &[]));
        // Length prefixes keep concatenations apart.
        assert_ne!(
            stage_key("ab", 1, &p(&[("c", "d")]), &[]),
            stage_key("a", 1, &p(&[("bc", "d")]), &[])
        );
    }

    #[test]
    fn hex_round_trip() {
        let k = stage_key("x", 3, &BTreeMap::new(), &[]);
        assert_eq!(Key::from_hex(&k.hex()), Some(k));
        assert_eq!(Key::from_hex("zz"), None);
    }
}
