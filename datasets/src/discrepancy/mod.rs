//! Data formats of the discrepancy workflow (one file per domain).

pub mod extrusion;
mod lines;
pub mod motion;

use lines::data_line;

/// The files of a hidden-effect set, relative to its folder, one layout for every
/// domain: `cases/case-NNN.csv` (data only, opaque names) and `answers.json` (the
/// domain, generator, seed and configuration — the twin included — and per case its
/// file and answer), so the data can be handed out without anything that reveals an
/// answer. Case numbers are a permutation of the generator's order drawn from `seed`
/// (the order is by effect, so a number in order would give the answer away).
/// `cases` yields each case's CSV text and answer.
pub fn hidden_set_files<C: serde::Serialize, A: serde::Serialize>(
    domain: fdmlab_models::discrepancy::DomainName,
    generator: &str,
    seed: u64,
    config: &C,
    cases: impl Iterator<Item = (String, A)>,
) -> Result<Vec<(String, Vec<u8>)>, crate::DatasetError> {
    let cases: Vec<(String, A)> = cases.collect();
    let numbers = opaque_numbers(cases.len(), seed);
    let mut files = Vec::new();
    let mut listed = Vec::new();
    for ((csv, answer), number) in cases.into_iter().zip(numbers) {
        let file = format!("cases/case-{number:03}.csv");
        listed.push((number, serde_json::json!({"file": file, "answer": answer})));
        files.push((file, csv.into_bytes()));
    }
    listed.sort_by_key(|(n, _)| *n);
    let listed: Vec<serde_json::Value> = listed.into_iter().map(|(_, v)| v).collect();
    let doc = serde_json::json!({"domain": domain, "generator": generator, "seed": seed, "config": config, "cases": listed});
    let text = serde_json::to_vec_pretty(&doc).map_err(|e| crate::DatasetError::Refused(format!("answers.json: {e}")))?;
    files.push(("answers.json".to_string(), text));
    Ok(files)
}

/// A permutation of `0..n` drawn from `seed`: the indices sorted by a SplitMix64
/// hash of (seed, index) (Steele, Lea & Flood 2014).
fn opaque_numbers(n: usize, seed: u64) -> Vec<usize> {
    let mix = |x: u64| {
        let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by_key(|&i| mix(mix(seed) ^ i as u64));
    let mut numbers = vec![0; n];
    for (number, &i) in order.iter().enumerate() {
        numbers[i] = number;
    }
    numbers
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn case_numbers_are_a_seeded_permutation() {
        let a = opaque_numbers(50, 3);
        let mut sorted = a.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..50).collect::<Vec<_>>());
        assert_eq!(a, opaque_numbers(50, 3));
        assert_ne!(a, opaque_numbers(50, 4));
        // Not the generator's order (P of the identity among 50! permutations is nil).
        assert_ne!(a, (0..50).collect::<Vec<_>>());
    }
}
