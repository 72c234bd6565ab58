//! The entropy coder of format 3's node payloads (strata-v3.md §4): static rANS over small
//! alphabets whose frequencies the file stores once (`CODE`), and a plain bit stream for the raw
//! low bits of large values. Integer arithmetic only, so every reader decodes the same symbols.
//!
//! A symbol of alphabet `a` with frequency `f` and cumulative frequency `c` (out of
//! [`PROB_SCALE`]) moves the decoder's 32-bit state `x` to `f·(x >> 11) + (x mod 2048) − c`, then
//! the state takes bytes while it is below [`RANS_L`]. The writer encodes symbols last to first,
//! starting from `x = RANS_L`, so a reader that decodes every symbol ends at `RANS_L` having read
//! every byte: a check on the whole stream for free.

/// Frequencies of an alphabet add up to `2^PROB_BITS`.
pub const PROB_BITS: u32 = 11;
pub const PROB_SCALE: u32 = 1 << PROB_BITS;
/// No symbol's frequency exceeds this (a file's tables are refused otherwise), so that every
/// symbol costs at least `log2(PROB_SCALE / MAX_FREQ)` ≈ 0.0227 bits and a stream of `n` bytes
/// holds fewer than [`MAX_SYMBOLS_PER_BYTE`]` · (n + 4)` symbols: decoding work is bounded by
/// the bytes.
pub const MAX_FREQ: u32 = PROB_SCALE - PROB_SCALE / 64;
pub const MAX_SYMBOLS_PER_BYTE: u64 = 353;
const OFFSET_SHIFT: u32 = 8 + PROB_BITS;
/// The state lies in `RANS_L .. 256·RANS_L` between symbols.
pub const RANS_L: u32 = 1 << 23;
/// Largest alphabet: symbols are bytes.
pub const MAX_SYMBOLS: usize = 256;
/// Symbols of the residual alphabet ([`bucket`]).
pub const BUCKETS: usize = 64;

/// One alphabet's frequencies, by symbol, adding up to [`PROB_SCALE`]; empty for an alphabet the
/// file never uses.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Freqs(pub Vec<u16>);

impl Freqs {
    /// Frequencies proportional to `counts`, each symbol that occurs at least 1, adding up to
    /// [`PROB_SCALE`]; trailing symbols that never occur are dropped. Empty when nothing occurs.
    pub fn from_counts(counts: &[u64]) -> Freqs {
        let n = counts.iter().rposition(|&c| c > 0).map_or(0, |i| i + 1);
        let counts = &counts[..n.min(MAX_SYMBOLS)];
        let total: u64 = counts.iter().sum();
        if total == 0 {
            return Freqs::default();
        }
        let scale = PROB_SCALE as u64;
        let mut f: Vec<i64> = counts
            .iter()
            .map(|&c| if c == 0 { 0 } else { ((c as u128 * scale as u128 + total as u128 / 2) / total as u128).max(1) as i64 })
            .collect();
        let mut sum: i64 = f.iter().sum();
        // Take from or give to the most frequent symbols, where a unit changes the cost least.
        while sum != scale as i64 {
            let step = if sum > scale as i64 { -1 } else { 1 };
            let i = (0..f.len())
                .filter(|&i| f[i] > 1 || (step > 0 && f[i] > 0))
                .max_by_key(|&i| (counts[i], std::cmp::Reverse(i)))
                .expect("a symbol occurs");
            f[i] += step;
            sum += step;
        }
        // No symbol above MAX_FREQ (at most one can be): the excess goes to a neighbour, which an
        // alphabet of one symbol gains though it never uses it.
        if let Some(i) = f.iter().position(|&x| x > MAX_FREQ as i64) {
            let j = if i + 1 < MAX_SYMBOLS { i + 1 } else { i - 1 };
            if j == f.len() {
                f.push(0);
            }
            f[j] += f[i] - MAX_FREQ as i64;
            f[i] = MAX_FREQ as i64;
        }
        Freqs(f.into_iter().map(|x| x as u16).collect())
    }

    /// Check stored frequencies: at most [`MAX_SYMBOLS`], none above [`MAX_FREQ`], adding up to
    /// [`PROB_SCALE`] (or none).
    pub fn check(&self) -> Result<(), String> {
        if self.0.len() > MAX_SYMBOLS {
            return Err(format!("{} symbols, at most {MAX_SYMBOLS}", self.0.len()));
        }
        if let Some(s) = self.0.iter().position(|&f| f as u32 > MAX_FREQ) {
            return Err(format!("symbol {s} has frequency {}, more than {MAX_FREQ}", self.0[s]));
        }
        let sum: u32 = self.0.iter().map(|&f| f as u32).sum();
        if !self.0.is_empty() && sum != PROB_SCALE {
            return Err(format!("frequencies add up to {sum}, not {PROB_SCALE}"));
        }
        Ok(())
    }

    /// Cumulative frequencies: `cum[s]` is the sum of the frequencies below `s`.
    fn cumulative(&self) -> Vec<u32> {
        let mut c = 0u32;
        self.0
            .iter()
            .map(|&f| {
                let below = c;
                c += f as u32;
                below
            })
            .collect()
    }
}

/// A decoding table: for each of the [`PROB_SCALE`] slots, the symbol, its frequency minus 1 and
/// the slot's offset within the symbol's range, packed as `symbol | (f − 1) << 8 | offset << (8 + PROB_BITS)`.
/// An empty alphabet decodes every slot as symbol 255 with frequency [`PROB_SCALE`] (the state
/// does not move), which no caller accepts.
#[derive(Clone)]
pub struct DecodeTable(Box<[u32]>);

impl DecodeTable {
    pub fn new(f: &Freqs) -> DecodeTable {
        let mut t = vec![0u32; PROB_SCALE as usize].into_boxed_slice();
        if f.0.is_empty() {
            for (slot, e) in t.iter_mut().enumerate() {
                *e = 0xFF | (PROB_SCALE - 1) << 8 | (slot as u32) << OFFSET_SHIFT;
            }
            return DecodeTable(t);
        }
        let mut slot = 0usize;
        for (s, &freq) in f.0.iter().enumerate() {
            for k in 0..freq as u32 {
                t[slot] = s as u32 | (freq as u32 - 1) << 8 | k << OFFSET_SHIFT;
                slot += 1;
            }
        }
        DecodeTable(t)
    }
}

/// Encoding tables: frequency and cumulative frequency of each symbol.
#[derive(Clone, Debug, Default)]
pub struct EncodeTable {
    freq: Vec<u32>,
    cum: Vec<u32>,
}

impl EncodeTable {
    pub fn new(f: &Freqs) -> EncodeTable {
        EncodeTable { freq: f.0.iter().map(|&x| x as u32).collect(), cum: f.cumulative() }
    }
}

/// Reads symbols from a rANS stream: 4 bytes of initial state (little-endian), then bytes as the
/// state needs them. Past the end it reads zeros and counts them, so a decoder checks once, at
/// [`RansReader::finish`].
pub struct RansReader<'a> {
    data: &'a [u8],
    pos: usize,
    x: u32,
}

impl<'a> RansReader<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        let mut r = RansReader { data, pos: 0, x: 0 };
        for k in 0..4 {
            r.x |= (r.byte() as u32) << (8 * k);
        }
        r
    }

    #[inline(always)]
    fn byte(&mut self) -> u8 {
        let b = self.data.get(self.pos).copied().unwrap_or(0);
        self.pos += 1;
        b
    }

    /// The next symbol of the alphabet `t`.
    #[inline(always)]
    pub fn get(&mut self, t: &DecodeTable) -> u32 {
        let e = t.0[(self.x & (PROB_SCALE - 1)) as usize];
        let freq = ((e >> 8) & (PROB_SCALE - 1)) + 1;
        self.x = freq.wrapping_mul(self.x >> PROB_BITS).wrapping_add(e >> OFFSET_SHIFT);
        if self.x < RANS_L {
            self.x = (self.x << 8) | self.byte() as u32;
            if self.x < RANS_L {
                self.x = (self.x << 8) | self.byte() as u32;
            }
        }
        e & 0xFF
    }

    /// Whether the stream ended exactly: every byte read, none past the end, and the state back
    /// where the writer began.
    pub fn finish(&self) -> Result<(), String> {
        if self.pos > self.data.len() {
            return Err(format!("the symbol stream of {} bytes ends early", self.data.len()));
        }
        if self.pos < self.data.len() {
            return Err(format!("{} bytes after the symbol stream's end", self.data.len() - self.pos));
        }
        if self.x != RANS_L {
            return Err(format!("the symbol stream ends in state {:#x}, not {RANS_L:#x}", self.x));
        }
        Ok(())
    }

    /// Bytes read so far.
    pub fn position(&self) -> usize {
        self.pos
    }
}

/// Encode `symbols` (alphabet, symbol), in the order a reader decodes them, with `tables`.
/// Every symbol must have a non-zero frequency in its alphabet.
pub fn encode(symbols: &[(u8, u8)], tables: &[EncodeTable]) -> Result<Vec<u8>, String> {
    let mut x = RANS_L;
    let mut out = Vec::with_capacity(symbols.len() / 2 + 8);
    for &(a, s) in symbols.iter().rev() {
        let t = &tables[a as usize];
        let f = t.freq.get(s as usize).copied().unwrap_or(0);
        if f == 0 {
            return Err(format!("symbol {s} of alphabet {a} has no frequency"));
        }
        let max = ((RANS_L >> PROB_BITS) << 8) * f;
        while x >= max {
            out.push(x as u8);
            x >>= 8;
        }
        x = ((x / f) << PROB_BITS) + (x % f) + t.cum[s as usize];
    }
    out.extend_from_slice(&x.to_be_bytes());
    out.reverse();
    Ok(out)
}

/// The residual alphabet's symbol of `u`, with the count and value of its raw low bits: values
/// 0–3 are symbols 0–3; a larger value of `b` bits is symbol `4 + 2(b − 3) + t`, `t` its bit below
/// the leading one, followed by its `b − 2` low bits.
#[inline(always)]
pub fn bucket(u: u32) -> (u8, u32, u32) {
    if u < 4 {
        return (u as u8, 0, 0);
    }
    let b = 32 - u.leading_zeros();
    let top = (u >> (b - 2)) & 1;
    (4 + 2 * (b - 3) as u8 + top as u8, b - 2, u & ((1 << (b - 2)) - 1))
}

/// The value of residual symbol `s` (below [`BUCKETS`]) whose raw bits are `raw(count)`; `raw`
/// is called for symbols 0–3 too, with a count of 0 (it must then read nothing and give 0), so
/// that decoding has no branch on the symbol, which would be mispredicted.
#[inline(always)]
pub fn unbucket(s: u32, raw: impl FnOnce(u32) -> u32) -> u32 {
    let extra = s.saturating_sub(2) >> 1;
    let head = if extra == 0 { s } else { (2 | (s & 1)) << extra };
    head | raw(extra)
}

/// Signed residuals as unsigned: 0, −1, 1, −2, … → 0, 1, 2, 3, ….
#[inline(always)]
pub fn zigzag(v: i32) -> u32 {
    ((v << 1) ^ (v >> 31)) as u32
}

#[inline(always)]
pub fn unzigzag(u: u32) -> i32 {
    (u >> 1) as i32 ^ -((u & 1) as i32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_round_trip() {
        for u in (0..5000u32).chain([u32::MAX, u32::MAX - 1, 1 << 31, (1 << 31) - 1, 123_456_789]) {
            let (s, n, v) = bucket(u);
            assert!((s as usize) < BUCKETS, "{u}");
            assert_eq!(
                unbucket(s as u32, |k| {
                    assert_eq!(k, n);
                    v
                }),
                u
            );
        }
        for v in [0, 1, -1, 2, -2, i32::MAX, i32::MIN, 77, -78] {
            assert_eq!(unzigzag(zigzag(v)), v);
        }
    }

    #[test]
    fn frequencies_add_up_and_keep_every_symbol() {
        for counts in [vec![1u64], vec![0, 0, 5], vec![1_000_000, 1, 1, 1], vec![3; 256], (0..256).map(|i| i * i).collect()] {
            let f = Freqs::from_counts(&counts);
            f.check().unwrap();
            for (i, &c) in counts.iter().enumerate() {
                assert_eq!(c > 0, f.0.get(i).is_some_and(|&x| x > 0), "{counts:?}");
            }
        }
        assert!(Freqs::from_counts(&[0, 0]).0.is_empty());
    }

    #[test]
    fn symbols_round_trip_and_the_stream_checks_itself() {
        let mut state = 0x1234_5678u32;
        let mut rand = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        let mut counts = [vec![0u64; 40], vec![0u64; 3], vec![0u64; 1]];
        let mut symbols = Vec::new();
        for _ in 0..20_000 {
            let a = (rand() % 3) as u8;
            let s = match a {
                0 => (rand() % 40).min(rand() % 40) as u8,
                1 => (rand() % 3) as u8,
                _ => 0,
            };
            counts[a as usize][s as usize] += 1;
            symbols.push((a, s));
        }
        let freqs: Vec<Freqs> = counts.iter().map(|c| Freqs::from_counts(c)).collect();
        let enc: Vec<EncodeTable> = freqs.iter().map(EncodeTable::new).collect();
        let dec: Vec<DecodeTable> = freqs.iter().map(DecodeTable::new).collect();
        let bytes = encode(&symbols, &enc).unwrap();
        let mut r = RansReader::new(&bytes);
        for &(a, s) in &symbols {
            assert_eq!(r.get(&dec[a as usize]), s as u32);
        }
        r.finish().unwrap();
        let mut damaged = bytes.clone();
        damaged[bytes.len() / 2] ^= 4;
        let mut r = RansReader::new(&damaged);
        let same = symbols.iter().all(|&(a, s)| r.get(&dec[a as usize]) == s as u32);
        assert!(!same || r.finish().is_err());
        let mut r = RansReader::new(&bytes[..bytes.len() - 1]);
        symbols.iter().for_each(|&(a, _)| {
            r.get(&dec[a as usize]);
        });
        assert!(r.finish().is_err());
        assert!(encode(&[(1, 7)], &enc).is_err());
    }
}
