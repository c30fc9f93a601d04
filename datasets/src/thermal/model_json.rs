//! State-space JSON for `fdmlab thermal place`:
//! `{"A":[[…],…],"B":[…],"C":[…],"D":0}` with optional `"dt_s"` (discrete).
//! `B` may be a flat column (one input) or rows; `C` a flat row or `[[…]]`;
//! `D` a number, a list or absent. An identified-model artifact (it has a
//! `"family"` key) is accepted too: its continuous form when it has one.

use crate::DatasetError;
use fdmlab_models::thermal::model::ThermalModel;
use fdmlab_models::thermal::ss::{SsMatrices, StateSpace};
use serde_json::Value;

fn numbers(v: &Value, file: &str, field: &str) -> Result<Vec<f64>, DatasetError> {
    match v {
        Value::Number(n) => Ok(vec![n.as_f64().unwrap_or(f64::NAN)]),
        Value::Array(items) => {
            let mut out = Vec::new();
            for (i, it) in items.iter().enumerate() {
                match it {
                    Value::Number(n) => out.push(n.as_f64().unwrap_or(f64::NAN)),
                    Value::Array(_) => out.extend(numbers(it, file, field)?),
                    _ => return Err(DatasetError::parse(file, 1, &format!("{field}[{i}]"), "expected a number")),
                }
            }
            Ok(out)
        }
        _ => Err(DatasetError::parse(file, 1, field, "expected a number or an array of numbers")),
    }
}

fn rows(v: &Value, file: &str, field: &str) -> Result<Vec<Vec<f64>>, DatasetError> {
    let Value::Array(items) = v else { return Err(DatasetError::parse(file, 1, field, "expected an array of rows")) };
    items
        .iter()
        .enumerate()
        .map(|(i, r)| match r {
            Value::Array(_) => numbers(r, file, &format!("{field}[{i}]")),
            Value::Number(_) => numbers(r, file, &format!("{field}[{i}]")),
            _ => Err(DatasetError::parse(file, 1, &format!("{field}[{i}]"), "expected a row of numbers")),
        })
        .collect()
}

/// Parse state-space JSON text.
pub fn parse(text: &str, file: &str) -> Result<StateSpace, DatasetError> {
    let v: Value = serde_json::from_str(text).map_err(|e| DatasetError::parse(file, e.line(), "json", e.to_string()))?;
    if v.get("family").is_some() {
        let model: ThermalModel = serde_json::from_value(v).map_err(|e| DatasetError::parse(file, 1, "model", e.to_string()))?;
        let m = model.continuous.as_ref().unwrap_or(&model.ss);
        return Ok(StateSpace::from_matrices(m)?);
    }
    let get = |k: &str| v.get(k).ok_or_else(|| DatasetError::parse(file, 1, k, "missing key"));
    let a = rows(get("A")?, file, "A")?;
    let n = a.len();
    if n == 0 || a.iter().any(|r| r.len() != n) {
        return Err(DatasetError::parse(file, 1, "A", format!("must be square; got {n} rows of lengths {:?}", a.iter().map(Vec::len).collect::<Vec<_>>())));
    }
    let b_raw = rows(get("B")?, file, "B")?;
    let b: Vec<Vec<f64>> = if b_raw.len() == n {
        b_raw
    } else {
        return Err(DatasetError::parse(file, 1, "B", format!("needs {n} entries (one per state), got {}", b_raw.len())));
    };
    let c = numbers(get("C")?, file, "C")?;
    if c.len() != n {
        return Err(DatasetError::parse(file, 1, "C", format!("needs {n} entries, got {}", c.len())));
    }
    let inputs = b.first().map_or(0, Vec::len);
    let d = match v.get("D") {
        None | Some(Value::Null) => vec![0.0; inputs],
        Some(x) => {
            let d = numbers(x, file, "D")?;
            if d.len() == 1 && inputs > 1 && d[0] == 0.0 {
                vec![0.0; inputs]
            } else {
                d
            }
        }
    };
    if d.len() != inputs {
        return Err(DatasetError::parse(file, 1, "D", format!("needs {inputs} entries, got {}", d.len())));
    }
    let dt_s = match v.get("dt_s") {
        None | Some(Value::Null) => None,
        Some(x) => Some(x.as_f64().ok_or_else(|| DatasetError::parse(file, 1, "dt_s", "expected a number"))?),
    };
    for (name, vals) in [("A", a.concat()), ("B", b.concat()), ("C", c.clone()), ("D", d.clone())] {
        if vals.iter().any(|x| !x.is_finite()) {
            return Err(DatasetError::parse(file, 1, name, "contains a non-finite number"));
        }
    }
    Ok(StateSpace::from_matrices(&SsMatrices { a, b, c, d, dt_s })?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn reads_the_documented_shape() {
        let ss = parse(r#"{"A":[[-0.1,0],[1,-0.5]],"B":[1,0],"C":[0,1],"D":0}"#, "ss.json").expect("ss");
        assert_eq!((ss.order(), ss.n_inputs(), ss.dt_s), (2, 1, None));
        assert_eq!(ss.b[(0, 0)], 1.0);
        let ss = parse(r#"{"A":[[0.9]],"B":[[0.1]],"C":[[1]],"dt_s":1}"#, "ss.json").expect("discrete");
        assert_eq!(ss.dt_s, Some(1.0));
    }

    #[test]
    fn errors_name_the_field() {
        for (text, field) in [
            (r#"{"A":[[1,2]],"B":[1],"C":[1]}"#, "A"),
            (r#"{"A":[[1]],"B":[1,2],"C":[1]}"#, "B"),
            (r#"{"A":[[1]],"B":[1],"C":[1,2]}"#, "C"),
            (r#"{"A":[[1]],"B":[1]}"#, "C"),
            (r#"{"A":[["x"]],"B":[1],"C":[1]}"#, "A[0][0]"),
            ("{", "json"),
        ] {
            let err = parse(text, "m.json").expect_err(text).to_string();
            assert!(err.starts_with(&format!("m.json:1: {field}:")), "{err}");
        }
    }

    proptest! {
        #[test]
        fn never_panics(text in ".{0,200}") {
            let _ = parse(&text, "x.json");
        }

        #[test]
        fn round_trips_square_models(n in 1usize..6, seed in 0u64..1000) {
            let a: Vec<Vec<f64>> = (0..n).map(|i| (0..n).map(|j| ((i * 7 + j * 3) as u64 ^ seed) as f64 / 1000.0 - 0.5).collect()).collect();
            let b: Vec<f64> = (0..n).map(|i| i as f64 + 1.0).collect();
            let c: Vec<f64> = (0..n).map(|i| 1.0 / (i as f64 + 1.0)).collect();
            let text = serde_json::json!({"A": a, "B": b, "C": c, "D": 0}).to_string();
            let ss = parse(&text, "p.json").expect("parse");
            prop_assert_eq!(ss.order(), n);
            // serde_json's default float parser is correct to ~2 ulp.
            prop_assert!((ss.a[(n - 1, 0)] - a[n - 1][0]).abs() <= 1e-15 * a[n - 1][0].abs().max(1.0));
        }
    }
}
