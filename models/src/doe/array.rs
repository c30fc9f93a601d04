//! Taguchi's standard three-level orthogonal arrays, built over GF(3).
//!
//! Every column of L9(3^4) and L27(3^13) is a linear form over GF(3) of the base
//! digits of the run number (a = slowest, c = fastest); the generator list below
//! reproduces Taguchi's published column order exactly (Taguchi 1987, "System of
//! Experimental Design", array tables; pinned by the full-table test). The base
//! columns of L27 are 1, 2 and 5; columns 3/4, 6/7 and 8/11 carry the
//! interactions 1×2, 1×5 and 2×5.

use crate::ModelError;

/// L27 column generators: coefficients of (a, b, c), columns 1..13.
const L27_GENERATORS: [[u8; 3]; 13] =
    [[1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0], [0, 0, 1], [1, 0, 1], [2, 0, 1], [0, 1, 1], [1, 1, 1], [2, 1, 1], [0, 2, 1], [1, 2, 1], [2, 2, 1]];
/// L9 column generators: coefficients of (a, b), columns 1..4.
const L9_GENERATORS: [[u8; 3]; 4] = [[1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]];

/// Default factor-to-column assignment of L27: the base columns 1, 2, 5 first, then
/// 9 and 10 (with five factors the fourth×fifth interaction partly aliases column 1:
/// no 5-factor assignment in 27 runs is free of main-effect/2-factor aliasing),
/// then the remaining columns.
const L27_ASSIGNMENT: [usize; 13] = [1, 2, 5, 9, 10, 12, 13, 3, 4, 6, 7, 8, 11];
const L9_ASSIGNMENT: [usize; 4] = [1, 2, 4, 3];

/// An orthogonal array with levels numbered from 1.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct OrthogonalArray {
    pub name: String,
    pub levels: u8,
    /// `rows[run][column]`, levels 1..=`levels`.
    pub rows: Vec<Vec<u8>>,
}

fn gf3(name: &str, generators: &[[u8; 3]], runs: usize) -> OrthogonalArray {
    let rows = (0..runs)
        .map(|run| {
            let digits = [(run / 9 % 3) as u8, (run / 3 % 3) as u8, (run % 3) as u8];
            // L9 uses two digits (a, b) = (run/3, run%3): shift so `a` is the slowest.
            let d = if runs == 9 { [digits[1], digits[2], 0] } else { digits };
            generators.iter().map(|g| (g[0] * d[0] + g[1] * d[1] + g[2] * d[2]) % 3 + 1).collect()
        })
        .collect();
    OrthogonalArray { name: name.to_string(), levels: 3, rows }
}

impl OrthogonalArray {
    /// Taguchi's standard L9(3^4).
    pub fn l9() -> Self {
        gf3("L9", &L9_GENERATORS, 9)
    }
    /// Taguchi's standard L27(3^13).
    pub fn l27() -> Self {
        gf3("L27", &L27_GENERATORS, 27)
    }
    /// An array by name (`L9`, `L27`, case-insensitive).
    pub fn by_name(name: &str) -> Result<Self, ModelError> {
        match name.to_ascii_uppercase().as_str() {
            "L9" => Ok(Self::l9()),
            "L27" => Ok(Self::l27()),
            _ => Err(ModelError::invalid("array", name, "known arrays: L9, L27")),
        }
    }
    /// Number of runs (rows).
    pub fn runs(&self) -> usize {
        self.rows.len()
    }
    /// Number of columns.
    pub fn columns(&self) -> usize {
        self.rows.first().map_or(0, Vec::len)
    }

    /// Strength-2 orthogonality: every pair of columns shows every pair of levels
    /// equally often (runs / levels²), and every column is balanced.
    pub fn is_orthogonal(&self) -> bool {
        let l = usize::from(self.levels);
        let n = self.runs();
        if l == 0 || n % (l * l) != 0 || self.rows.iter().any(|r| r.len() != self.columns()) {
            return false;
        }
        for i in 0..self.columns() {
            for j in (i + 1)..self.columns() {
                let mut counts = vec![0usize; l * l];
                for r in &self.rows {
                    let (a, b) = (usize::from(r[i]), usize::from(r[j]));
                    if a == 0 || b == 0 || a > l || b > l {
                        return false;
                    }
                    counts[(a - 1) * l + (b - 1)] += 1;
                }
                if counts.iter().any(|&c| c != n / (l * l)) {
                    return false;
                }
            }
        }
        true
    }

    /// Default 1-based columns for `factors` factors (see the module doc).
    pub fn default_columns(&self, factors: usize) -> Result<Vec<usize>, ModelError> {
        let order: &[usize] = match self.name.as_str() {
            "L27" => &L27_ASSIGNMENT,
            "L9" => &L9_ASSIGNMENT,
            _ => &[],
        };
        if factors == 0 || factors > order.len() {
            return Err(ModelError::invalid("factors", factors, &format!("{} holds 1..={} factors", self.name, order.len())));
        }
        Ok(order[..factors].to_vec())
    }

    /// The sub-array of the given 1-based columns: `[run][factor]` levels.
    pub fn select(&self, columns: &[usize]) -> Result<Vec<Vec<u8>>, ModelError> {
        for (i, &c) in columns.iter().enumerate() {
            if c == 0 || c > self.columns() {
                return Err(ModelError::invalid("column", c, &format!("{} has columns 1..={}", self.name, self.columns())));
            }
            if columns[..i].contains(&c) {
                return Err(ModelError::invalid("column", c, "assigned twice"));
            }
        }
        Ok(self.rows.iter().map(|r| columns.iter().map(|&c| r[c - 1]).collect()).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Taguchi's published L27(3^13), row by row.
    const L27_PUBLISHED: [&str; 27] = [
        "1111111111111",
        "1111222222222",
        "1111333333333",
        "1222111222333",
        "1222222333111",
        "1222333111222",
        "1333111333222",
        "1333222111333",
        "1333333222111",
        "2123123123123",
        "2123231231231",
        "2123312312312",
        "2231123231312",
        "2231231312123",
        "2231312123231",
        "2312123312231",
        "2312231123312",
        "2312312231123",
        "3132132132132",
        "3132213213213",
        "3132321321321",
        "3213132213321",
        "3213213321132",
        "3213321132213",
        "3321132321213",
        "3321213132321",
        "3321321213132",
    ];

    #[test]
    fn l27_matches_the_published_table_and_is_orthogonal() {
        let a = OrthogonalArray::l27();
        for (row, text) in a.rows.iter().zip(L27_PUBLISHED) {
            let want: Vec<u8> = text.bytes().map(|b| b - b'0').collect();
            assert_eq!(row, &want);
        }
        assert!(a.is_orthogonal());
        assert_eq!((a.runs(), a.columns()), (27, 13));
    }

    #[test]
    fn l9_matches_the_published_table() {
        let want = ["1111", "1222", "1333", "2123", "2231", "2312", "3132", "3213", "3321"];
        let a = OrthogonalArray::l9();
        for (row, text) in a.rows.iter().zip(want) {
            assert_eq!(row, &text.bytes().map(|b| b - b'0').collect::<Vec<u8>>());
        }
        assert!(a.is_orthogonal());
    }

    #[test]
    fn a_broken_array_is_not_orthogonal() {
        let mut a = OrthogonalArray::l27();
        a.rows[3][4] = 3;
        assert!(!a.is_orthogonal());
    }

    #[test]
    fn select_and_assignment() {
        let a = OrthogonalArray::l27();
        assert_eq!(a.default_columns(5).expect("ok"), vec![1, 2, 5, 9, 10]);
        assert!(a.default_columns(14).is_err());
        assert!(a.select(&[1, 1]).is_err());
        assert!(a.select(&[14]).is_err());
        let s = a.select(&[1, 2, 5, 9, 10]).expect("ok");
        assert_eq!(s[26], vec![3, 3, 3, 1, 3]);
    }
}
