//! Names that come from specs and become file names: only a safe alphabet, so
//! no name can climb out of the store (`../../x`, `/etc`, `a/b` are refused).

/// True for `[A-Za-z0-9][A-Za-z0-9._-]*`, at most 100 characters.
pub fn is_safe_name(name: &str) -> bool {
    let mut chars = name.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphanumeric())
        && name.len() <= 100
        && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'))
}

#[cfg(test)]
mod tests {
    use super::is_safe_name;

    #[test]
    fn refuses_paths() {
        for bad in ["", "..", "../x", "a/b", "/etc", ".hidden", "a\\b", "a b", "ünï"] {
            assert!(!is_safe_name(bad), "{bad}");
        }
        for good in ["thermal-first-order", "pa_pla.v2", "L27"] {
            assert!(is_safe_name(good), "{good}");
        }
    }
}
