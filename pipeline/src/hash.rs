//! Content hashes: blake3, written as 64 lower-case hex digits.

use serde::{Deserialize, Serialize};

/// A blake3 content hash, 64 lower-case hex digits.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Hash(pub String);

impl Hash {
    /// Hash of `bytes`.
    pub fn of(bytes: &[u8]) -> Hash {
        Hash(blake3::hash(bytes).to_hex().to_string())
    }
    /// The hex digits.
    pub fn as_str(&self) -> &str {
        &self.0
    }
    /// Parse a full 64-digit hex hash.
    pub fn parse(s: &str) -> Option<Hash> {
        (s.len() == 64 && s.bytes().all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase())).then(|| Hash(s.to_string()))
    }
}

impl std::fmt::Display for Hash {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
