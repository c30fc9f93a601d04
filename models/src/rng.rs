//! Seeded randomness: every draw in fdmlab comes from a spec's seed.

use rand::SeedableRng;

/// The one random generator type used everywhere (portable, reproducible).
pub type Rng = rand_chacha::ChaCha8Rng;

/// A generator for `seed`, optionally split into an independent `stream`
/// (so that adding a draw in one place does not shift another's numbers).
pub fn seeded(seed: u64, stream: u64) -> Rng {
    let mut rng = Rng::seed_from_u64(seed);
    rng.set_stream(stream);
    rng
}
