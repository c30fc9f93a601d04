//! G-code reader shared by every experiment: a lexer for classic word commands
//! (`G1 X10 E0.5 F1200 ; comment`) and Klipper extended commands
//! (`SET_PRESSURE_ADVANCE ADVANCE=0.05`), and a modal interpreter that turns
//! motion commands into straight [`Move`]s, and a streaming reader of the XY
//! moves of real slicer output ([`stream::moves`]). Hand-written rather than the `gcode`
//! crate, which is `no_std`-first and does not read Klipper's `KEY=VALUE` commands.

mod lex;
mod machine;
pub mod stream;

pub use lex::{parse_number, Head, Lexed, LineLexer};
pub use machine::{Machine, Move};

use crate::DatasetError;

/// One command of a G-code program.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Command {
    /// 1-based line number in the source text.
    pub line: usize,
    /// Upper-case command name: `G1`, `M900`, `SET_PRESSURE_ADVANCE`.
    pub name: String,
    /// Letter-number words after the name (`X10` → `('X', 10.0)`).
    pub words: Vec<(char, f64)>,
    /// `KEY=VALUE` arguments of extended commands, keys upper-cased.
    pub args: Vec<(String, String)>,
    /// Text after `;`, trimmed.
    pub comment: Option<String>,
}

impl Command {
    /// Value of word `letter` (upper case), if present.
    pub fn word(&self, letter: char) -> Option<f64> {
        self.words.iter().find(|(l, _)| *l == letter).map(|(_, v)| *v)
    }
    /// Value of extended argument `key` (upper case), if present.
    pub fn arg(&self, key: &str) -> Option<&str> {
        self.args.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
    }
    /// True for `G0`/`G1` (and their zero-padded forms).
    pub fn is_move(&self) -> bool {
        matches!(self.name.as_str(), "G0" | "G1" | "G00" | "G01")
    }
}

/// Parse a whole program. Blank and comment-only lines yield no command;
/// `file` names the source in errors.
pub fn parse(text: &str, file: &str) -> Result<Vec<Command>, DatasetError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        if let Some(cmd) = parse_line(raw, i + 1, file)? {
            out.push(cmd);
        }
    }
    Ok(out)
}

/// Parse one line (1-based `line` for errors).
pub fn parse_line(raw: &str, line: usize, file: &str) -> Result<Option<Command>, DatasetError> {
    let mut lexer = LineLexer::default();
    let bytes = raw.as_bytes();
    let lexed = lexer.lex(bytes, line, file)?;
    let Some(head) = lexed.head else {
        return Ok(None);
    };
    let text = |r: std::ops::Range<usize>| String::from_utf8_lossy(&bytes[r]).into_owned();
    Ok(Some(Command {
        line,
        name: text(head.name).to_ascii_uppercase(),
        words: std::mem::take(&mut lexer.words),
        args: lexer.args.into_iter().map(|(k, v)| (text(k).to_ascii_uppercase(), text(v))).collect(),
        comment: lexed.comment.map(text),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn reads_classic_and_extended_commands() {
        let p =
            parse("G1 X10 Y-2.5 E0.3 F1200 ; fast\n\n; only comment\nSET_PRESSURE_ADVANCE ADVANCE=0.05\nN12 M900 K0.1*77\nG28 X", "t.gcode").expect("parses");
        assert_eq!(p.len(), 4);
        assert_eq!(p[0].word('X'), Some(10.0));
        assert_eq!(p[0].word('E'), Some(0.3));
        assert_eq!(p[0].comment.as_deref(), Some("fast"));
        assert_eq!(p[1].arg("ADVANCE"), Some("0.05"));
        assert_eq!((p[2].name.as_str(), p[2].word('K'), p[2].line), ("M900", Some(0.1), 5));
        assert!(p[3].word('X').is_some_and(f64::is_nan));
    }

    #[test]
    fn names_line_and_field_of_bad_numbers() {
        let err = parse("G1 X1\nG1 Xabc", "bad.gcode").expect_err("bad number");
        assert_eq!(err.to_string(), "bad.gcode:2: X: `abc` is not a number");
    }

    proptest! {
        #[test]
        fn never_panics_on_arbitrary_text(s in "\\PC{0,200}") {
            let _ = parse(&s, "fuzz");
        }

        #[test]
        fn round_trips_written_moves(x in -1e4f64..1e4, y in -1e4f64..1e4, e in -10f64..10.0) {
            let text = format!("G1 X{x} Y{y} E{e}");
            let c = parse(&text, "p").expect("parses");
            prop_assert_eq!(c[0].word('X'), Some(x));
            prop_assert_eq!(c[0].word('Y'), Some(y));
            prop_assert_eq!(c[0].word('E'), Some(e));
        }
    }
}
