//! Artifact keys: a 128-bit hash of everything that went into making an artifact.
//!
//! A stage hashes its input files, its parameters and the keys of the artifacts it reads into a
//! [`Key`] with a [`KeyHasher`], stores the key in the artifact header, and later compares it
//! with [`crate::Artifact::expect_key`] to tell whether the artifact is stale.

use std::fmt;
use std::fs::File;
use std::io::{self, Read};
use std::path::Path;

use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::{Serialize, Serializer};
use xxhash_rust::xxh3::Xxh3;

/// A 128-bit artifact key (xxh3-128 of the inputs and parameters).
///
/// Displays as 32 lowercase hex characters. Serializes as that hex string in human-readable
/// formats (TOML, JSON) and as 16 raw bytes in binary ones (MessagePack).
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct Key(pub [u8; 16]);

impl Key {
    /// Parses 32 hex characters (either case). Returns `None` for anything else.
    pub fn from_hex(hex: &str) -> Option<Key> {
        let hex = hex.as_bytes();
        if hex.len() != 32 {
            return None;
        }
        let mut bytes = [0u8; 16];
        for (byte, pair) in bytes.iter_mut().zip(hex.chunks_exact(2)) {
            *byte = (hex_digit(pair[0])? << 4) | hex_digit(pair[1])?;
        }
        Some(Key(bytes))
    }

    /// The 16 bytes of the key.
    pub fn as_bytes(&self) -> &[u8; 16] {
        &self.0
    }
}

fn hex_digit(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    }
}

impl fmt::Display for Key {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for byte in self.0 {
            write!(f, "{byte:02x}")?;
        }
        Ok(())
    }
}

impl fmt::Debug for Key {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Key({self})")
    }
}

impl Serialize for Key {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        if serializer.is_human_readable() {
            serializer.collect_str(self)
        } else {
            serializer.serialize_bytes(&self.0)
        }
    }
}

impl<'de> serde::Deserialize<'de> for Key {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Key, D::Error> {
        struct KeyVisitor;

        impl<'de> Visitor<'de> for KeyVisitor {
            type Value = Key;

            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a key: 32 hex characters or 16 bytes")
            }

            fn visit_str<E: de::Error>(self, v: &str) -> Result<Key, E> {
                Key::from_hex(v).ok_or_else(|| E::invalid_value(de::Unexpected::Str(v), &self))
            }

            fn visit_bytes<E: de::Error>(self, v: &[u8]) -> Result<Key, E> {
                <[u8; 16]>::try_from(v)
                    .map(Key)
                    .map_err(|_| E::invalid_length(v.len(), &self))
            }

            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Key, A::Error> {
                let mut bytes = [0u8; 16];
                for (i, byte) in bytes.iter_mut().enumerate() {
                    *byte = seq
                        .next_element()?
                        .ok_or_else(|| de::Error::invalid_length(i, &self))?;
                }
                if seq.next_element::<u8>()?.is_some() {
                    return Err(de::Error::invalid_length(17, &self));
                }
                Ok(Key(bytes))
            }
        }

        if deserializer.is_human_readable() {
            deserializer.deserialize_str(KeyVisitor)
        } else {
            deserializer.deserialize_bytes(KeyVisitor)
        }
    }
}

/// Builds a [`Key`] by hashing a sequence of values with streaming xxh3-128.
///
/// Every update is framed with its length (a little-endian `u64` before the bytes), so the
/// hasher sees a sequence of values rather than one byte string: `update(b"ab"); update(b"c")`
/// and `update(b"a"); update(b"bc")` give different keys. Order matters.
///
/// ```
/// use pc_artifact::KeyHasher;
/// let mut h = KeyHasher::new();
/// h.update_str("octree").update_serialize(&(8u32, 0.5f32));
/// let key = h.finish();
/// assert_eq!(key.to_string().len(), 32);
/// ```
#[derive(Clone)]
pub struct KeyHasher {
    state: Xxh3,
}

impl Default for KeyHasher {
    fn default() -> Self {
        KeyHasher::new()
    }
}

impl fmt::Debug for KeyHasher {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("KeyHasher").finish_non_exhaustive()
    }
}

impl KeyHasher {
    /// A hasher with nothing hashed yet.
    pub fn new() -> KeyHasher {
        KeyHasher { state: Xxh3::new() }
    }

    fn frame(&mut self, len: u64) {
        self.state.update(&len.to_le_bytes());
    }

    /// Hashes one byte string (length-prefixed).
    pub fn update(&mut self, bytes: &[u8]) -> &mut Self {
        self.frame(bytes.len() as u64);
        self.state.update(bytes);
        self
    }

    /// Hashes one string (its UTF-8 bytes, length-prefixed).
    pub fn update_str(&mut self, s: &str) -> &mut Self {
        self.update(s.as_bytes())
    }

    /// Hashes a value through its MessagePack encoding (struct fields by name, length-prefixed).
    ///
    /// # Panics
    ///
    /// If the value cannot be encoded as MessagePack, which only happens for a `Serialize` impl
    /// that fails on purpose or a sequence serialized without a known length: a bug in the
    /// caller, not a property of the input data.
    pub fn update_serialize<T: Serialize + ?Sized>(&mut self, value: &T) -> &mut Self {
        let bytes = rmp_serde::to_vec_named(value)
            .unwrap_or_else(|e| panic!("KeyHasher::update_serialize: cannot encode value: {e}"));
        self.update(&bytes)
    }

    /// Hashes the contents of a file, streamed (length-prefixed).
    ///
    /// Fails if the file cannot be read, is not a regular file, or if its length changes while
    /// it is being read.
    pub fn update_file(&mut self, path: impl AsRef<Path>) -> io::Result<&mut Self> {
        // A FIFO or a device never ends (and opening a FIFO blocks): refuse it before opening.
        if !std::fs::metadata(path.as_ref())?.is_file() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "not a regular file (a folder, FIFO, socket or device): only files are hashed",
            ));
        }
        let mut file = File::open(path.as_ref())?;
        let len = file.metadata()?.len();
        // Hash into a copy, so that a failure leaves `self` as it was.
        let mut state = self.state.clone();
        state.update(&len.to_le_bytes());
        let mut buf = vec![0u8; 1 << 16];
        let mut read = 0u64;
        loop {
            let n = match file.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            };
            state.update(&buf[..n]);
            read += n as u64;
        }
        if read != len {
            return Err(io::Error::other(format!(
                "the file changed while it was hashed: {len} bytes expected, {read} read"
            )));
        }
        self.state = state;
        Ok(self)
    }

    /// Hashes another artifact's key (typically the key of an input artifact).
    pub fn update_key(&mut self, key: &Key) -> &mut Self {
        self.update(&key.0)
    }

    /// The key of everything hashed so far.
    pub fn finish(&self) -> Key {
        Key(self.state.digest128().to_be_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_round_trip() {
        let key = Key(*b"\x00\x01\x02\x03\x04\x05\x06\x07\x08\x09\x0a\x0b\xfc\xfd\xfe\xff");
        let hex = key.to_string();
        assert_eq!(hex, "000102030405060708090a0bfcfdfeff");
        assert_eq!(Key::from_hex(&hex), Some(key));
        assert_eq!(Key::from_hex(&hex.to_uppercase()), Some(key));
        assert_eq!(format!("{key:?}"), format!("Key({hex})"));
        assert_eq!(Key::from_hex(""), None);
        assert_eq!(Key::from_hex(&hex[..31]), None);
        assert_eq!(Key::from_hex(&format!("{}g", &hex[..31])), None);
        assert_eq!(Key::from_hex("é0102030405060708090a0bfcfdfeff"), None);
    }

    #[test]
    fn serde_binary_is_raw_bytes() {
        let key = KeyHasher::new().update_str("x").finish();
        let bytes = rmp_serde::to_vec(&key).unwrap();
        assert_eq!(bytes.len(), 2 + 16, "msgpack bin8 header + 16 bytes");
        let back: Key = rmp_serde::from_slice(&bytes).unwrap();
        assert_eq!(back, key);
        // An array of 16 numbers is accepted too.
        let seq = rmp_serde::to_vec(&key.0.to_vec()).unwrap();
        let back: Key = rmp_serde::from_slice(&seq).unwrap();
        assert_eq!(back, key);
    }

    #[test]
    fn is_xxh3_128_of_the_framed_values() {
        let mut framed = Vec::new();
        framed.extend_from_slice(&4u64.to_le_bytes());
        framed.extend_from_slice(b"pcgi");
        framed.extend_from_slice(&3u64.to_le_bytes());
        framed.extend_from_slice(&[1, 2, 3]);
        let expected = xxhash_rust::xxh3::xxh3_128(&framed).to_be_bytes();
        let key = KeyHasher::new()
            .update_str("pcgi")
            .update(&[1, 2, 3])
            .finish();
        assert_eq!(key, Key(expected));
    }

    #[test]
    fn framing_separates_values() {
        let ab_c = KeyHasher::new().update(b"ab").update(b"c").finish();
        let a_bc = KeyHasher::new().update(b"a").update(b"bc").finish();
        let abc = KeyHasher::new().update(b"abc").finish();
        assert_ne!(ab_c, a_bc);
        assert_ne!(ab_c, abc);
        assert_ne!(
            KeyHasher::new().finish(),
            KeyHasher::new().update(b"").finish()
        );
    }
}
