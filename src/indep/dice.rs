//! The generator's own random source: xoshiro256** seeded through SplitMix64.
//!
//! Every random choice of a case comes from a stream named by (case seed, purpose), so the
//! command, the machine's nominal offsets, each hidden effect and the sensor noise draw from
//! separate streams. A case with an extra effect therefore keeps the command, the noise and
//! the other effects of the same seed, which lets a test difference two records.

/// A deterministic stream of random numbers.
#[derive(Debug, Clone)]
pub struct Dice {
    s: [u64; 4],
}

/// One SplitMix64 step: spreads a counter over all 64 bits.
fn splitmix(x: &mut u64) -> u64 {
    *x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *x;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A stable 64-bit tag of a text (FNV-1a), so streams can be named by words.
pub fn tag(text: &str) -> u64 {
    text.bytes().fold(0xCBF2_9CE4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3)
    })
}

impl Dice {
    /// The stream `purpose` of case `seed`.
    pub fn new(seed: u64, purpose: &str) -> Dice {
        let mut x = seed ^ tag(purpose).rotate_left(17);
        let s = [
            splitmix(&mut x),
            splitmix(&mut x),
            splitmix(&mut x),
            splitmix(&mut x),
        ];
        Dice { s }
    }

    /// The next 64 random bits (xoshiro256**).
    pub fn bits(&mut self) -> u64 {
        let out = self.s[1].wrapping_mul(5).rotate_left(7).wrapping_mul(9);
        let t = self.s[1] << 17;
        self.s[2] ^= self.s[0];
        self.s[3] ^= self.s[1];
        self.s[1] ^= self.s[2];
        self.s[0] ^= self.s[3];
        self.s[2] ^= t;
        self.s[3] = self.s[3].rotate_left(45);
        out
    }

    /// Uniform in [0, 1) with 53 random bits.
    pub fn unit(&mut self) -> f64 {
        (self.bits() >> 11) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }

    /// Uniform in [lo, hi).
    pub fn between(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Log-uniform in [lo, hi) (both > 0): for scale parameters spanning a decade.
    pub fn log_between(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + (hi.ln() - lo.ln()) * self.unit()).exp()
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }

    /// +1 or −1 with equal odds.
    pub fn sign(&mut self) -> f64 {
        if self.bits() >> 63 == 0 { 1.0 } else { -1.0 }
    }

    /// Uniform integer in 0..n (0 when n is 0).
    pub fn index(&mut self, n: usize) -> usize {
        if n == 0 {
            return 0;
        }
        ((self.unit() * n as f64) as usize).min(n - 1)
    }

    /// Standard normal deviate (Marsaglia's polar method).
    pub fn gauss(&mut self) -> f64 {
        loop {
            let a = 2.0 * self.unit() - 1.0;
            let b = 2.0 * self.unit() - 1.0;
            let r2 = a * a + b * b;
            if r2 > 0.0 && r2 < 1.0 {
                return a * (-2.0 * r2.ln() / r2).sqrt();
            }
        }
    }
}
