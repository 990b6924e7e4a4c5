//! The one random generator of the workspace: SplitMix64, seeded explicitly (no global state).

/// SplitMix64 (Steele, Lea, Flood 2014): a tiny, fast, seedable 64-bit generator.
#[derive(Debug, Clone)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)` with 53 random bits.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in `[lo, hi)` (or `lo` when `hi <= lo`).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        if hi <= lo {
            lo
        } else {
            lo + (hi - lo) * self.next_f64()
        }
    }

    /// Two independent standard normal values (Box–Muller on two uniforms).
    pub fn normal_pair(&mut self) -> (f64, f64) {
        // 1 - u is in (0, 1], so the logarithm is finite.
        let r = (-2.0 * (1.0 - self.next_f64()).ln()).sqrt();
        let (s, c) = (std::f64::consts::TAU * self.next_f64()).sin_cos();
        (r * c, r * s)
    }

    /// Uniform integer in `[-k, k]`.
    pub fn symmetric_int(&mut self, k: u32) -> i32 {
        let span = 2 * u64::from(k) + 1;
        (self.next_u64() % span) as i32 - k as i32
    }
}

/// A seed derived from `seed` for the named purpose `stream` (one SplitMix64 output of their
/// mix): independent streams from one user seed.
pub fn derive_seed(seed: u64, stream: u64) -> u64 {
    SplitMix64::new(seed ^ stream.wrapping_mul(0xd1b5_4a32_d192_ed03)).next_u64()
}
