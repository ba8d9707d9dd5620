//! A seeded mutator: inputs derived from a corpus of valid ones by small random edits, as a
//! mutation fuzzer makes them, deterministic for a given seed.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Values that break parsers and arithmetic, as 4-byte little-endian words: zero, one, the
/// extremes of u32 and i32, and the f32 NaN, infinities, huge, tiny and negative zero.
const WORDS: [u32; 14] = [
    0,
    1,
    0xFFFF_FFFF,
    0x7FFF_FFFF,
    0x8000_0000,
    0x7FC0_0000, // NaN
    0x7F80_0000, // +inf
    0xFF80_0000, // -inf
    0x7F7F_FFFF, // f32::MAX
    0x0000_0001, // smallest subnormal
    0x8000_0000, // -0.0
    0x3F80_0000, // 1.0
    0x4E6E_6B28, // 1e9
    0x7149_F2CA, // 1e30
];

/// Text fragments that stress a TOML config: extreme numbers, wrong types, odd keys.
const TOKENS: [&str; 16] = [
    "0",
    "-1",
    "4294967295",
    "18446744073709551615",
    "1e30",
    "-1e30",
    "nan",
    "inf",
    "0.0",
    "\"\"",
    "\".\"",
    "[]",
    "[1e38, 1e38, 1e38]",
    "{}",
    "true",
    "\"/dev/zero\"",
];

/// Derives inputs from a corpus by random edits.
pub struct Mutator {
    rng: Pcg64Mcg,
}

impl Mutator {
    pub fn new(seed: u64) -> Mutator {
        Mutator {
            rng: Pcg64Mcg::seed_from_u64(seed),
        }
    }

    /// A random number below `n` (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        self.rng.random_range(0..n.max(1))
    }

    /// One to four random byte-level edits of `input`.
    pub fn bytes(&mut self, input: &[u8]) -> Vec<u8> {
        let mut v = input.to_vec();
        for _ in 0..1 + self.below(4) {
            self.edit(&mut v);
        }
        v
    }

    fn edit(&mut self, v: &mut Vec<u8>) {
        let n = v.len();
        match self.below(8) {
            // Flip one bit.
            0 if n > 0 => {
                let i = self.below(n);
                v[i] ^= 1 << self.below(8);
            }
            // A byte set to an edge value.
            1 if n > 0 => {
                let i = self.below(n);
                v[i] = [0u8, 0xFF, 0x7F, 0x80, b'\n', b' ', b'-'][self.below(7)];
            }
            // A word set to a value that breaks arithmetic, at a 4-byte boundary.
            2 if n >= 4 => {
                let i = self.below(n / 4) * 4;
                v[i..i + 4].copy_from_slice(&WORDS[self.below(WORDS.len())].to_le_bytes());
            }
            // Truncated.
            3 if n > 0 => v.truncate(self.below(n)),
            // Random bytes inserted.
            4 => {
                let at = self.below(n + 1);
                let k = 1 + self.below(16);
                let bytes: Vec<u8> = (0..k).map(|_| self.rng.random()).collect();
                v.splice(at..at, bytes);
            }
            // A range deleted.
            5 if n > 0 => {
                let a = self.below(n);
                let b = (a + 1 + self.below(64)).min(n);
                v.drain(a..b);
            }
            // A range duplicated.
            6 if n > 0 => {
                let a = self.below(n);
                let b = (a + 1 + self.below(64)).min(n);
                let chunk = v[a..b].to_vec();
                let at = self.below(v.len() + 1);
                v.splice(at..at, chunk);
            }
            // A word set to a random value.
            _ if n >= 4 => {
                let i = self.below(n / 4) * 4;
                let w: u32 = self.rng.random();
                v[i..i + 4].copy_from_slice(&w.to_le_bytes());
            }
            _ => v.push(self.rng.random()),
        }
    }

    /// One to three line- and token-level edits of a text: a line deleted, duplicated or
    /// moved; a value replaced by an extreme one; a key's name changed; bytes flipped.
    pub fn text(&mut self, input: &str) -> String {
        let mut lines: Vec<String> = input.lines().map(str::to_string).collect();
        for _ in 0..1 + self.below(3) {
            let n = lines.len();
            match self.below(6) {
                0 if n > 0 => {
                    lines.remove(self.below(n));
                }
                1 if n > 0 => {
                    let l = lines[self.below(n)].clone();
                    let at = self.below(n + 1);
                    lines.insert(at, l);
                }
                2 if n > 1 => {
                    let (a, b) = (self.below(n), self.below(n));
                    lines.swap(a, b);
                }
                3 if n > 0 => {
                    // `key = value`: a new value.
                    let i = self.below(n);
                    if let Some((k, _)) = lines[i].split_once('=') {
                        lines[i] = format!("{k}= {}", TOKENS[self.below(TOKENS.len())]);
                    }
                }
                4 if n > 0 => {
                    // A key's name changed (unknown keys must be refused).
                    let i = self.below(n);
                    if let Some((k, v)) = lines[i].split_once('=') {
                        lines[i] = format!("{}x ={v}", k.trim_end());
                    }
                }
                _ => {
                    let t = lines.join("\n");
                    let v = self.bytes(t.as_bytes());
                    return String::from_utf8_lossy(&v).into_owned();
                }
            }
        }
        lines.join("\n")
    }
}
