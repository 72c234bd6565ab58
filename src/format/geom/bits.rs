//! The bit-level tools of format 3's node codec (spec §8.2 of strata-v3.md): an MSB-first bit
//! stream, adaptive Rice codes for residuals and canonical prefix codes for small alphabets.
//! Integer arithmetic only, so that every reader decodes the same values.

/// Unary prefixes of this many zeros mark an escaped Rice value: 32 raw bits follow.
pub const RICE_ESCAPE: u32 = 20;
/// Largest Rice parameter.
pub const RICE_MAX_K: u32 = 24;
/// A Rice state halves its sums when its count reaches this.
pub const RICE_WINDOW: u32 = 32;
/// Longest prefix code, in bits.
pub const MAX_CODE_BITS: u32 = 12;

/// Bits written most significant first, packed into bytes; the last byte is padded with zeros.
#[derive(Default)]
pub struct BitWriter {
    out: Vec<u8>,
    acc: u64,
    n: u32,
}

impl BitWriter {
    /// Append the low `bits` (≤ 32) bits of `value`.
    pub fn put(&mut self, value: u32, bits: u32) {
        debug_assert!(bits <= 32 && (bits == 32 || value >> bits == 0));
        self.acc = (self.acc << bits) | value as u64;
        self.n += bits;
        while self.n >= 8 {
            self.n -= 8;
            self.out.push((self.acc >> self.n) as u8);
        }
    }

    /// Bits written so far.
    pub fn len(&self) -> u64 {
        8 * self.out.len() as u64 + self.n as u64
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn finish(mut self) -> Vec<u8> {
        if self.n > 0 {
            self.out.push((self.acc << (8 - self.n)) as u8);
        }
        self.out
    }
}

/// Reads what [`BitWriter`] wrote. Reading past the end yields zeros and is reported by
/// [`BitReader::overrun`], so a decoder checks once at the end instead of at every read.
pub struct BitReader<'a> {
    data: &'a [u8],
    pos: usize,
    buf: u64,
    avail: u32,
    consumed: u64,
}

impl<'a> BitReader<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        let mut r = BitReader { data, pos: 0, buf: 0, avail: 0, consumed: 0 };
        r.refill();
        r
    }

    #[inline]
    fn refill(&mut self) {
        if self.pos + 8 <= self.data.len() {
            let word = u64::from_be_bytes(self.data[self.pos..self.pos + 8].try_into().expect("8 bytes"));
            self.buf |= word >> self.avail;
            self.pos += ((63 - self.avail) >> 3) as usize;
            self.avail |= 56;
        } else {
            while self.avail <= 56 {
                let byte = self.data.get(self.pos).copied().unwrap_or(0);
                self.buf |= (byte as u64) << (56 - self.avail);
                self.avail += 8;
                self.pos += 1;
            }
        }
    }

    /// The next `bits` (1..=32) bits, without consuming them.
    #[inline]
    fn peek(&mut self, bits: u32) -> u32 {
        if self.avail < bits {
            self.refill();
        }
        (self.buf >> (64 - bits)) as u32
    }

    #[inline]
    fn skip(&mut self, bits: u32) {
        self.buf <<= bits;
        self.avail -= bits;
        self.consumed += bits as u64;
    }

    /// Read `bits` (0..=32) bits.
    #[inline]
    pub fn get(&mut self, bits: u32) -> u32 {
        if bits == 0 {
            return 0;
        }
        let v = self.peek(bits);
        self.skip(bits);
        v
    }

    /// Read `bits` (0..=32) bits without a branch on `bits` (0 reads nothing and gives 0): for
    /// values whose width is data, which a branch would mispredict.
    #[inline(always)]
    pub fn get_any(&mut self, bits: u32) -> u32 {
        if self.avail < bits {
            self.refill();
        }
        let v = ((self.buf >> (63 - bits)) >> 1) as u32;
        self.buf = (self.buf << (bits >> 1)) << (bits - (bits >> 1));
        self.avail -= bits;
        self.consumed += bits as u64;
        v
    }

    /// Bits read so far.
    pub fn consumed(&self) -> u64 {
        self.consumed
    }

    /// Whether more bits were read than the data holds.
    pub fn overrun(&self) -> bool {
        self.consumed > 8 * self.data.len() as u64
    }
}

/// An adaptive Rice coder's state: the parameter follows the running mean of the values coded
/// (as in JPEG-LS), so no table travels with the data.
#[derive(Clone, Copy, Debug)]
pub struct Rice {
    sum: u64,
    count: u32,
}

impl Rice {
    /// A state whose first parameter is `k`.
    pub const fn new(k: u32) -> Self {
        Rice { sum: 1 << k, count: 1 }
    }

    /// The parameter: the smallest `k` with `count · 2^k ≥ sum`, at most [`RICE_MAX_K`].
    #[inline]
    pub fn k(&self) -> u32 {
        // Start from the difference of bit lengths, at most one off the answer either way.
        let count = self.count as u64;
        let mut k = (64 - self.sum.leading_zeros()).saturating_sub(64 - count.leading_zeros()).min(RICE_MAX_K);
        while k > 0 && (count << (k - 1)) >= self.sum {
            k -= 1;
        }
        while k < RICE_MAX_K && (count << k) < self.sum {
            k += 1;
        }
        k
    }

    #[inline]
    fn update(&mut self, u: u32) {
        self.sum += u as u64;
        self.count += 1;
        if self.count >= RICE_WINDOW {
            self.sum = (self.sum + 1) >> 1;
            self.count >>= 1;
        }
    }

    pub fn put(&mut self, w: &mut BitWriter, u: u32) {
        let k = self.k();
        let q = u >> k;
        if q < RICE_ESCAPE {
            w.put(1, q + 1);
            if k > 0 {
                w.put(u & ((1 << k) - 1), k);
            }
        } else {
            w.put(0, RICE_ESCAPE);
            w.put(u, 32);
        }
        self.update(u);
    }

    #[inline]
    pub fn get(&mut self, r: &mut BitReader) -> u32 {
        let k = self.k();
        let zeros = r.peek(32).leading_zeros();
        let u = if zeros < RICE_ESCAPE {
            r.skip(zeros + 1);
            (zeros << k) | r.get(k)
        } else {
            r.skip(RICE_ESCAPE);
            r.get(32)
        };
        self.update(u);
        u
    }

    /// Code a signed value (zigzag: 0, −1, 1, −2, … as 0, 1, 2, 3, …).
    pub fn put_signed(&mut self, w: &mut BitWriter, v: i32) {
        self.put(w, zigzag(v));
    }

    #[inline]
    pub fn get_signed(&mut self, r: &mut BitReader) -> i32 {
        unzigzag(self.get(r))
    }
}

#[inline]
pub fn zigzag(v: i32) -> u32 {
    ((v << 1) ^ (v >> 31)) as u32
}

#[inline]
pub fn unzigzag(u: u32) -> i32 {
    ((u >> 1) as i32) ^ -((u & 1) as i32)
}

/// A canonical prefix code given by the length of each symbol's code (0 = unused), assigned as in
/// DEFLATE (RFC 1951 §3.2.2): shorter codes first, and within a length, smaller symbols first.
pub struct PrefixCode {
    codes: Vec<(u32, u32)>,
    /// For every `MAX_CODE_BITS`-bit window: the symbol it starts with and that symbol's length.
    table: Vec<(u8, u8)>,
}

impl PrefixCode {
    /// Panics on lengths that do not form a complete prefix code: they are constants of the spec.
    pub fn new(lengths: &[u8]) -> Self {
        let mut codes = vec![(0u32, 0u32); lengths.len()];
        let mut code = 0u32;
        let mut table = vec![(0u8, 0u8); 1 << MAX_CODE_BITS];
        for len in 1..=MAX_CODE_BITS {
            for (s, &l) in lengths.iter().enumerate() {
                if l as u32 == len {
                    codes[s] = (code, len);
                    let first = (code << (MAX_CODE_BITS - len)) as usize;
                    for e in &mut table[first..first + (1 << (MAX_CODE_BITS - len))] {
                        *e = (s as u8, len as u8);
                    }
                    code += 1;
                }
            }
            code <<= 1;
        }
        assert_eq!(code, 1 << (MAX_CODE_BITS + 1), "prefix code lengths {lengths:?} are not complete");
        PrefixCode { codes, table }
    }

    pub fn put(&self, w: &mut BitWriter, symbol: usize) {
        let (code, len) = self.codes[symbol];
        w.put(code, len);
    }

    #[inline]
    pub fn get(&self, r: &mut BitReader) -> usize {
        let (s, len) = self.table[r.peek(MAX_CODE_BITS) as usize];
        r.skip(len as u32);
        s as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_of_any_width_match_plain_reads() {
        let mut w = BitWriter::default();
        let widths: Vec<u32> = (0..400).map(|i| (i * 7) % 33).collect();
        for (i, &n) in widths.iter().enumerate() {
            w.put(if n == 0 { 0 } else { (i as u32).wrapping_mul(0x9E37_79B9) >> (32 - n) }, n);
        }
        let bytes = w.finish();
        let (mut a, mut b) = (BitReader::new(&bytes), BitReader::new(&bytes));
        for &n in &widths {
            assert_eq!(a.get_any(n), b.get(n), "{n} bits");
            assert_eq!(a.consumed(), b.consumed());
        }
        assert_eq!(a.get_any(0), 0);
        assert!(!a.overrun());
    }

    #[test]
    fn values_round_trip() {
        let code = PrefixCode::new(&[1, 2, 3, 4, 4]);
        let mut w = BitWriter::default();
        let (mut a, mut b) = (Rice::new(0), Rice::new(4));
        let values: Vec<i32> = (0..2000).map(|i| ((i * 7919) % 301) - 150 + if i % 97 == 0 { 1 << 28 } else { 0 }).collect();
        for (i, &v) in values.iter().enumerate() {
            code.put(&mut w, i % 5);
            a.put_signed(&mut w, v);
            b.put(&mut w, (i % 13) as u32);
            w.put(i as u32 & 7, 3);
        }
        let bytes = w.finish();
        let mut r = BitReader::new(&bytes);
        let (mut a, mut b) = (Rice::new(0), Rice::new(4));
        for (i, &v) in values.iter().enumerate() {
            assert_eq!(code.get(&mut r), i % 5);
            assert_eq!(a.get_signed(&mut r), v);
            assert_eq!(b.get(&mut r), (i % 13) as u32);
            assert_eq!(r.get(3), i as u32 & 7);
        }
        assert!(!r.overrun());
        r.get(32);
        r.get(32);
        assert!(r.overrun());
    }

    #[test]
    fn the_rice_parameter_is_the_smallest_that_covers_the_mean() {
        for sum in 0..5000u64 {
            for count in 1..40u32 {
                let r = Rice { sum, count };
                let mut k = 0;
                while k < RICE_MAX_K && ((count as u64) << k) < sum {
                    k += 1;
                }
                assert_eq!(r.k(), k, "sum {sum} count {count}");
            }
        }
    }

    #[test]
    fn zigzag_is_a_bijection_at_the_ends() {
        for v in [0, -1, 1, i32::MAX, i32::MIN, 12345, -12345] {
            assert_eq!(unzigzag(zigzag(v)), v);
        }
    }
}
