//! Feature tables for the K_A regressor: any CSV with named numeric and categorical
//! columns. A column is numeric when every cell parses as a number, categorical
//! otherwise; categoricals are one-hot encoded (levels sorted, so the encoding is
//! reproducible). The encoding is stored with the model to encode `--set` queries.

use super::csv::read_strings;
use crate::DatasetError;
use fdmlab_models::regress::Design;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// How one input column becomes model features.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum Feature {
    Numeric { name: String },
    Categorical { name: String, levels: Vec<String> },
}

impl Feature {
    pub fn name(&self) -> &str {
        match self {
            Feature::Numeric { name } | Feature::Categorical { name, .. } => name,
        }
    }
}

/// The input columns, in order, and how they expand.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Encoding {
    pub target: String,
    pub features: Vec<Feature>,
}

impl Encoding {
    /// Expanded feature names (`hotend_c`, `material=PLA`, …).
    pub fn columns(&self) -> Vec<String> {
        let mut out = Vec::new();
        for f in &self.features {
            match f {
                Feature::Numeric { name } => out.push(name.clone()),
                Feature::Categorical { name, levels } => out.extend(levels.iter().map(|l| format!("{name}={l}"))),
            }
        }
        out
    }

    /// Encode one query given as `column → value` text; every feature must be given.
    pub fn encode(&self, values: &BTreeMap<String, String>) -> Result<Vec<f64>, DatasetError> {
        for k in values.keys() {
            if !self.features.iter().any(|f| f.name().eq_ignore_ascii_case(k)) {
                let known: Vec<&str> = self.features.iter().map(Feature::name).collect();
                return Err(DatasetError::Refused(format!("unknown feature `{k}` (the model uses {})", known.join(", "))));
            }
        }
        let mut out = Vec::new();
        for f in &self.features {
            let v = values
                .iter()
                .find(|(k, _)| k.eq_ignore_ascii_case(f.name()))
                .map(|(_, v)| v.trim())
                .ok_or_else(|| DatasetError::Refused(format!("missing feature `{}`", f.name())))?;
            match f {
                Feature::Numeric { name } => {
                    let x: f64 = v.parse().map_err(|_| DatasetError::Refused(format!("{name}: `{v}` is not a number")))?;
                    if !x.is_finite() {
                        return Err(DatasetError::Refused(format!("{name}: `{v}` is not finite")));
                    }
                    out.push(x);
                }
                Feature::Categorical { name, levels } => {
                    let i = levels
                        .iter()
                        .position(|l| l.eq_ignore_ascii_case(v))
                        .ok_or_else(|| DatasetError::Refused(format!("{name}: `{v}` was not in the training data ({})", levels.join(", "))))?;
                    out.extend((0..levels.len()).map(|j| if j == i { 1.0 } else { 0.0 }));
                }
            }
        }
        Ok(out)
    }
}

/// A loaded feature table: the numeric design plus its encoding and raw rows.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureTable {
    pub design: Design,
    pub encoding: Encoding,
    /// Each row's input values as text (for reports and group labels).
    pub raw: Vec<Vec<String>>,
}

/// Load `target` and `features` (all other columns when `None`) from CSV bytes.
pub fn load(bytes: &[u8], file: &str, target: &str, features: Option<&[String]>) -> Result<FeatureTable, DatasetError> {
    let t = read_strings(bytes, file)?;
    let ti = t.find(target).ok_or_else(|| DatasetError::parse(file, 1, target, format!("no column `{target}` (columns: {})", t.columns.join(", "))))?;
    let fi: Vec<usize> = match features {
        Some(list) => {
            let mut v = Vec::new();
            for name in list {
                let i = t.find(name).ok_or_else(|| DatasetError::parse(file, 1, name, format!("no column `{name}` (columns: {})", t.columns.join(", "))))?;
                if i == ti {
                    return Err(DatasetError::parse(file, 1, name, "the target cannot also be a feature"));
                }
                if v.contains(&i) {
                    return Err(DatasetError::parse(file, 1, name, "listed twice"));
                }
                v.push(i);
            }
            v
        }
        None => (0..t.columns.len()).filter(|&i| i != ti).collect(),
    };
    if fi.is_empty() {
        return Err(DatasetError::parse(file, 1, target, "no feature columns"));
    }
    if t.rows.len() < 2 {
        return Err(DatasetError::parse(file, 2, target, format!("{} data rows: need at least 2", t.rows.len())));
    }
    // Every used cell must be present.
    for (r, row) in t.rows.iter().enumerate() {
        for &c in fi.iter().chain(std::iter::once(&ti)) {
            if row.get(c).cloned().flatten().is_none() {
                return Err(DatasetError::parse(file, r + 2, &t.columns[c], "empty cell"));
            }
        }
    }
    let cell = |r: usize, c: usize| t.rows[r].get(c).cloned().flatten().unwrap_or_default();
    let mut y = Vec::with_capacity(t.rows.len());
    for r in 0..t.rows.len() {
        let s = cell(r, ti);
        let v: f64 = s.parse().map_err(|_| DatasetError::parse(file, r + 2, target, format!("`{s}` is not a number")))?;
        if !v.is_finite() {
            return Err(DatasetError::parse(file, r + 2, target, format!("`{s}` is not finite")));
        }
        y.push(v);
    }
    let mut encoding = Encoding { target: t.columns[ti].trim().to_string(), features: Vec::new() };
    for &c in &fi {
        let name = t.columns[c].trim().to_string();
        let is_number = |r: usize| cell(r, c).parse::<f64>().map(f64::is_finite).unwrap_or(false);
        let numbers = (0..t.rows.len()).filter(|&r| is_number(r)).count();
        // A column that is mostly numbers with a few other cells is a typo
        // (`2l5` for 215), not a category: name the first offending cell.
        if numbers < t.rows.len() && 2 * numbers > t.rows.len() {
            let r = (0..t.rows.len()).find(|&r| !is_number(r)).unwrap_or(0);
            return Err(DatasetError::parse(
                file,
                r + 2,
                &name,
                format!("`{}` is not a number, but {numbers} of {} cells in this column are", cell(r, c), t.rows.len()),
            ));
        }
        if numbers == t.rows.len() {
            encoding.features.push(Feature::Numeric { name });
        } else {
            let mut levels: Vec<String> = (0..t.rows.len()).map(|r| cell(r, c)).collect();
            levels.sort();
            levels.dedup();
            encoding.features.push(Feature::Categorical { name, levels });
        }
    }
    let mut x = Vec::new();
    let mut group = Vec::with_capacity(t.rows.len());
    let mut group_ids: BTreeMap<String, u32> = BTreeMap::new();
    let mut raw = Vec::with_capacity(t.rows.len());
    for r in 0..t.rows.len() {
        let values: BTreeMap<String, String> = fi.iter().map(|&c| (t.columns[c].trim().to_string(), cell(r, c))).collect();
        x.extend(encoding.encode(&values).map_err(|e| DatasetError::parse(file, r + 2, "features", e.to_string()))?);
        let key: Vec<String> =
            encoding.features.iter().filter(|f| matches!(f, Feature::Categorical { .. })).map(|f| values.get(f.name()).cloned().unwrap_or_default()).collect();
        let next = group_ids.len() as u32;
        group.push(*group_ids.entry(key.join("\u{1f}")).or_insert(next));
        raw.push(fi.iter().map(|&c| cell(r, c)).collect());
    }
    let design = Design::new(encoding.columns(), x, y, group)?;
    Ok(FeatureTable { design, encoding, raw })
}

/// Range of each numeric column among the rows of one categorical level (what the
/// model has seen, so exports do not extrapolate, e.g. PLA at 260 °C).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelSupport {
    pub column: String,
    pub level: String,
    pub ranges: BTreeMap<String, (f64, f64)>,
}

impl FeatureTable {
    /// Numeric ranges per categorical level.
    pub fn support(&self) -> Vec<LevelSupport> {
        let mut out = Vec::new();
        for (ci, f) in self.encoding.features.iter().enumerate() {
            let Feature::Categorical { name, levels } = f else { continue };
            for level in levels {
                let mut ranges: BTreeMap<String, (f64, f64)> = BTreeMap::new();
                for row in self.raw.iter().filter(|r| r.get(ci) == Some(level)) {
                    for (nj, g) in self.encoding.features.iter().enumerate() {
                        if let (Feature::Numeric { name: nn }, Some(Ok(v))) = (g, row.get(nj).map(|s| s.parse::<f64>())) {
                            let e = ranges.entry(nn.clone()).or_insert((v, v));
                            e.0 = e.0.min(v);
                            e.1 = e.1.max(v);
                        }
                    }
                }
                out.push(LevelSupport { column: name.clone(), level: level.clone(), ranges });
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_hot_and_groups() {
        let csv = "material,hotend_c,extruder,k\nPLA,200,bowden,0.7\nPETG,230,direct,0.1\nPLA,210,direct,0.06\n";
        let t = load(csv.as_bytes(), "f.csv", "k", None).expect("valid");
        assert_eq!(t.design.feature_names, vec!["material=PETG", "material=PLA", "hotend_c", "extruder=bowden", "extruder=direct"]);
        assert_eq!(t.design.row(0), &[0.0, 1.0, 200.0, 1.0, 0.0]);
        assert_eq!(t.design.group, vec![0, 1, 2]);
        let q: BTreeMap<String, String> =
            [("material", "petg"), ("hotend_c", "220"), ("extruder", "direct")].iter().map(|(a, b)| (a.to_string(), b.to_string())).collect();
        assert_eq!(t.encoding.encode(&q).expect("known levels"), vec![1.0, 0.0, 220.0, 0.0, 1.0]);
        let sup = t.support();
        let pla = sup.iter().find(|s| s.level == "PLA").expect("PLA");
        assert_eq!(pla.ranges.get("hotend_c"), Some(&(200.0, 210.0)));
    }

    #[test]
    fn many_levels_and_rows() {
        // 3000 rows, 60 materials × 25 printers: encoding stays fast and exact.
        let mut csv = String::from("material,printer,t,k\n");
        for i in 0..3000 {
            csv.push_str(&format!("m{},p{},{},{}\n", i % 60, i % 25, 200 + i % 40, 0.01 * (i % 97) as f64));
        }
        let t = load(csv.as_bytes(), "big.csv", "k", Some(&["material".into(), "printer".into(), "t".into()])).expect("valid");
        assert_eq!(t.design.cols(), 60 + 25 + 1);
        assert_eq!(t.design.rows(), 3000);
    }

    #[test]
    fn errors_name_row_and_column() {
        let e = load(b"a,k\n1,2\nx,\n", "f.csv", "k", None);
        assert!(matches!(e, Err(DatasetError::Parse { line: 3, ref field, .. }) if field == "k"));
        let e = load(b"a,k\n1,2\n2,zz\n", "f.csv", "k", None);
        assert!(matches!(e, Err(DatasetError::Parse { line: 3, ref field, .. }) if field == "k"));
        let e = load(b"a,k\n1,2\n2,3\n", "f.csv", "k", Some(&["b".into()]));
        assert!(matches!(e, Err(DatasetError::Parse { line: 1, ref field, .. }) if field == "b"));
        // A typo in a numeric column is an error, not a new category.
        let e = load(b"hotend_c,k\n210,1\n2l5,2\n220,3\n", "f.csv", "k", None);
        assert!(matches!(e, Err(DatasetError::Parse { line: 3, ref field, .. }) if field == "hotend_c"), "{e:?}");
        // A real categorical column (no numbers, or numbers only as a minority) is fine.
        assert!(load(b"m,k\nPLA,1\nPETG,2\n0.4,3\n", "f.csv", "k", None).is_ok());
    }

    proptest::proptest! {
        #[test]
        fn load_never_panics(text in "[a-c0-9,.\\n-]{0,200}") {
            let _ = load(text.as_bytes(), "p.csv", "a", None);
        }
    }
}
