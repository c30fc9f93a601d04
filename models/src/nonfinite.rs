//! Serde for `f64` data that may be non-finite. JSON has no NaN or ±∞ (serde_json
//! writes them as `null`, then cannot read `null` back into an `f64`), so these
//! write a non-finite value as `null` and read `null` as NaN. Use with
//! `#[serde(with = "fdmlab_models::nonfinite::vec")]` (or `matrix`, `map`).

use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::collections::BTreeMap;

fn out(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

fn back(v: Option<f64>) -> f64 {
    v.unwrap_or(f64::NAN)
}

/// A single `f64`.
pub mod scalar {
    use super::*;

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        out(*v).serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(back(Option::<f64>::deserialize(d)?))
    }
}

/// `Vec<f64>`.
pub mod vec {
    use super::*;

    pub fn serialize<S: Serializer>(v: &[f64], s: S) -> Result<S::Ok, S::Error> {
        v.iter().map(|x| out(*x)).collect::<Vec<_>>().serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        Ok(Vec::<Option<f64>>::deserialize(d)?.into_iter().map(back).collect())
    }
}

/// `Vec<Vec<f64>>` (a table of rows).
pub mod matrix {
    use super::*;

    pub fn serialize<S: Serializer>(m: &[Vec<f64>], s: S) -> Result<S::Ok, S::Error> {
        m.iter().map(|r| r.iter().map(|x| out(*x)).collect::<Vec<_>>()).collect::<Vec<_>>().serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec<f64>>, D::Error> {
        Ok(Vec::<Vec<Option<f64>>>::deserialize(d)?.into_iter().map(|r| r.into_iter().map(back).collect()).collect())
    }
}

/// `BTreeMap<String, f64>` (named metrics).
pub mod map {
    use super::*;

    pub fn serialize<S: Serializer>(m: &BTreeMap<String, f64>, s: S) -> Result<S::Ok, S::Error> {
        m.iter().map(|(k, v)| (k, out(*v))).collect::<BTreeMap<_, _>>().serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<BTreeMap<String, f64>, D::Error> {
        Ok(BTreeMap::<String, Option<f64>>::deserialize(d)?.into_iter().map(|(k, v)| (k, back(v))).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Serialize, Deserialize)]
    struct T {
        #[serde(with = "super::vec")]
        v: Vec<f64>,
        #[serde(with = "super::matrix")]
        m: Vec<Vec<f64>>,
        #[serde(with = "super::map")]
        k: BTreeMap<String, f64>,
    }

    #[test]
    fn non_finite_values_survive_a_json_round_trip() {
        let t = T {
            v: vec![1.5, f64::NAN],
            m: vec![vec![f64::NEG_INFINITY, 2.0]],
            k: [("rms".to_string(), f64::INFINITY), ("fit".to_string(), 97.5)].into_iter().collect(),
        };
        let json = serde_json::to_string(&t).expect("json");
        assert_eq!(json, r#"{"v":[1.5,null],"m":[[null,2.0]],"k":{"fit":97.5,"rms":null}}"#);
        let back: T = serde_json::from_str(&json).expect("read back");
        assert_eq!((back.v[0], back.m[0][1], back.k["fit"]), (1.5, 2.0, 97.5));
        assert!(back.v[1].is_nan() && back.m[0][0].is_nan() && back.k["rms"].is_nan());
    }
}
