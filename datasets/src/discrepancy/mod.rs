//! Data formats of the discrepancy workflow (one file per domain).

pub mod extrusion;
mod lines;
pub mod motion;

use lines::data_line;

/// The files of a hidden-effect set, relative to its folder: `cases/<id>.csv` (data
/// only) and `answers.json` (the domain, generator, configuration and seed, and per
/// case its file and answer), so the data can be handed out without the answers.
/// `cases` yields each case's id, CSV text and answer.
pub fn hidden_set_files<C: serde::Serialize, A: serde::Serialize>(
    domain: &str,
    generator: &str,
    seed: u64,
    config: &C,
    cases: impl Iterator<Item = (String, String, A)>,
) -> Result<Vec<(String, Vec<u8>)>, crate::DatasetError> {
    let mut files = Vec::new();
    let mut listed = Vec::new();
    for (id, csv, answer) in cases {
        let file = format!("cases/{id}.csv");
        listed.push(serde_json::json!({"file": file, "answer": answer}));
        files.push((file, csv.into_bytes()));
    }
    let doc = serde_json::json!({"domain": domain, "generator": generator, "seed": seed, "config": config, "cases": listed});
    let text = serde_json::to_vec_pretty(&doc).map_err(|e| crate::DatasetError::Refused(format!("answers.json: {e}")))?;
    files.push(("answers.json".to_string(), text));
    Ok(files)
}
