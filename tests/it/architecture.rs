//! The architecture map's rule "no cycles" (docs/ARCHITECTURE.md), checked on
//! the source: inside each crate, no module reaches itself through `use`
//! paths (`crate::…`, `super::…`). A module and its own ancestors or
//! descendants are not counted (a parent re-exporting its children and a
//! child using its parent's items is how Rust modules are built); an inline
//! `#[cfg(test)]` module at a file's end is skipped (its `super` is the file).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Module path (segments) of each `.rs` file under a crate's `src`.
fn modules(src: &Path) -> BTreeMap<Vec<String>, String> {
    let mut out = BTreeMap::new();
    let mut stack = vec![src.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("read src dir") {
            let path = entry.expect("dir entry").path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            if path.extension().is_none_or(|e| e != "rs") {
                continue;
            }
            let rel = path.strip_prefix(src).expect("under src").with_extension("");
            let mut segs: Vec<String> = rel.iter().map(|s| s.to_string_lossy().into_owned()).collect();
            if matches!(segs.last().map(String::as_str), Some("mod" | "lib" | "main")) {
                segs.pop();
            }
            out.insert(segs, std::fs::read_to_string(&path).expect("read source"));
        }
    }
    out
}

/// The paths a file's `use` items and expressions name after `crate::`/`super::`
/// (one level of `{…}` groups expanded), as (base module, segments).
fn paths(module: &[String], text: &str) -> Vec<Vec<String>> {
    let body = text.split("\n#[cfg(test)]").next().unwrap_or(text);
    let code: String = body.lines().filter(|l| !l.trim_start().starts_with("//")).collect::<Vec<_>>().join("\n");
    let ident = |s: &str| s.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect::<String>();
    let mut out = Vec::new();
    for (start, prefix) in code.match_indices("crate::").map(|(i, _)| (i, "crate::")).chain(code.match_indices("super::").map(|(i, _)| (i, "super::"))) {
        // `super::super::x` is taken once, from its first `super`.
        if prefix == "super::" && code[..start].ends_with("super::") {
            continue;
        }
        if start > 0 && code[..start].chars().next_back().is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue;
        }
        let mut base: Vec<String> = if prefix == "crate::" { Vec::new() } else { module[..module.len().saturating_sub(1)].to_vec() };
        let mut rest = &code[start + prefix.len()..];
        while let Some(r) = rest.strip_prefix("super::") {
            base.pop();
            rest = r;
        }
        let tails: Vec<String> = match rest.strip_prefix('{') {
            Some(group) => group.split('}').next().unwrap_or("").split(',').map(|s| s.trim().to_string()).collect(),
            None => vec![rest.to_string()],
        };
        for tail in tails {
            let mut p = base.clone();
            let mut t = tail.as_str();
            loop {
                let id = ident(t);
                if id.is_empty() {
                    break;
                }
                p.push(id.clone());
                match t[id.len()..].strip_prefix("::") {
                    Some(next) => t = next,
                    None => break,
                }
            }
            out.push(p);
        }
    }
    out
}

fn is_prefix(a: &[String], b: &[String]) -> bool {
    a.len() <= b.len() && a == &b[..a.len()]
}

/// Edges between modules that are not ancestor and descendant.
fn graph(mods: &BTreeMap<Vec<String>, String>) -> BTreeMap<Vec<String>, BTreeSet<Vec<String>>> {
    let mut g: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = BTreeMap::new();
    for (m, text) in mods {
        for p in paths(m, text) {
            // The deepest module the path names.
            let target = (0..=p.len()).rev().map(|n| p[..n].to_vec()).find(|q| mods.contains_key(q)).unwrap_or_default();
            if !is_prefix(&target, m) && !is_prefix(m, &target) {
                g.entry(m.clone()).or_default().insert(target);
            }
        }
    }
    g
}

/// One cycle of the graph, if any (depth-first search with a path stack).
fn cycle(g: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>) -> Option<Vec<Vec<String>>> {
    fn visit(
        n: &Vec<String>,
        g: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>,
        state: &mut BTreeMap<Vec<String>, u8>,
        path: &mut Vec<Vec<String>>,
    ) -> Option<Vec<Vec<String>>> {
        state.insert(n.clone(), 1);
        path.push(n.clone());
        for m in g.get(n).into_iter().flatten() {
            match state.get(m).copied().unwrap_or(0) {
                1 => {
                    let at = path.iter().position(|p| p == m).unwrap_or(0);
                    let mut c = path[at..].to_vec();
                    c.push(m.clone());
                    return Some(c);
                }
                0 => {
                    if let Some(c) = visit(m, g, state, path) {
                        return Some(c);
                    }
                }
                _ => {}
            }
        }
        path.pop();
        state.insert(n.clone(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for n in g.keys() {
        if state.get(n).copied().unwrap_or(0) == 0 {
            if let Some(c) = visit(n, g, &mut state, &mut Vec::new()) {
                return Some(c);
            }
        }
    }
    None
}

#[test]
fn no_crate_has_a_module_cycle() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let found: Vec<String> = ["src", "pipeline/src", "datasets/src", "models/src", "reports/src"]
        .iter()
        .filter_map(|krate| {
            let c = cycle(&graph(&modules(&root.join(krate))))?;
            let names: Vec<String> = c.iter().map(|m| if m.is_empty() { "(root)".into() } else { m.join("::") }).collect();
            Some(format!("{krate}: module cycle {}", names.join(" → ")))
        })
        .collect();
    assert!(found.is_empty(), "{}", found.join("\n"));
}

#[test]
fn the_cycle_check_finds_a_planted_cycle() {
    let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    let mods = BTreeMap::from([
        (s(&[]), "pub mod a;\npub mod b;\npub use a::X;\n".to_string()),
        (s(&["a"]), "use super::b::Y;\nuse super::X as _;\n".to_string()),
        (s(&["b"]), "use crate::{a::X, c};\n#[cfg(test)]\nmod tests { use super::*; }\n".to_string()),
        (s(&["c"]), "// use crate::a;\n".to_string()),
    ]);
    let g = graph(&mods);
    assert_eq!(cycle(&g), Some(vec![s(&["a"]), s(&["b"]), s(&["a"])]));
    // Without b → a there is none (root ↔ a is parent and child; c's comment is not a use).
    let mods: BTreeMap<_, _> = mods.into_iter().map(|(k, v)| if k == s(&["b"]) { (k, "use crate::c;\n".to_string()) } else { (k, v) }).collect();
    assert_eq!(cycle(&graph(&mods)), None);
}

/// docs/limits.md lists each checked parameter type's limits table; every row
/// must be a row of the doc table in the source file it names (the code's
/// table is the owner, the page a checked copy), and every source names a table.
#[test]
fn the_limits_page_copies_the_types_own_tables() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let page = std::fs::read_to_string(root.join("docs/limits.md")).expect("docs/limits.md");
    let mut sources = 0;
    for section in page.split("\n## ").skip(1) {
        let title = section.lines().next().unwrap_or("");
        let path = section.split("Source: `").nth(1).and_then(|s| s.split('`').next()).unwrap_or_else(|| panic!("section {title} names no source"));
        let code = std::fs::read_to_string(root.join(path)).unwrap_or_else(|e| panic!("{path}: {e}"));
        let doc_rows: BTreeSet<&str> = code
            .lines()
            .filter_map(|l| l.trim_start().strip_prefix("/// ").or_else(|| l.trim_start().strip_prefix("//! ")))
            .filter(|l| l.starts_with('|'))
            .collect();
        let rows: Vec<&str> = section.lines().filter(|l| l.starts_with('|')).collect();
        assert!(rows.len() > 2, "section {title} has no table");
        for row in rows {
            assert!(doc_rows.contains(row), "docs/limits.md, section {title}: row not in {path}'s doc table:\n{row}");
        }
        sources += 1;
    }
    assert!(sources >= 8, "{sources} sections");
}
