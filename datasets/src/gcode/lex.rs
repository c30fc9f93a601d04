//! Byte-level lexer of one G-code line, shared by the owned [`super::parse_line`]
//! and the streaming reader. It allocates nothing: words land in a reused
//! buffer and names, comments and `KEY=VALUE` arguments are byte ranges of the
//! line, so non-UTF-8 bytes in comments are harmless.

use std::ops::Range;

use crate::DatasetError;

/// What one line holds, as ranges into the line's bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct Lexed {
    /// The command, if the line has one.
    pub head: Option<Head>,
    /// Text after `;`, trimmed.
    pub comment: Option<Range<usize>>,
}

/// The command name of a line.
#[derive(Debug, Clone, PartialEq)]
pub struct Head {
    /// The name as written (`G1`, `g01`, `SET_PRESSURE_ADVANCE`).
    pub name: Range<usize>,
    /// Upper-case letter and integer number of a classic command (`G01` → `(b'G', 1)`);
    /// `None` for extended commands and sub-codes such as `G29.1`.
    pub code: Option<(u8, u32)>,
    /// True for a classic `G`/`M`/`T` command with letter-number words.
    pub classic: bool,
}

/// Reused buffers of lexed words and arguments.
#[derive(Debug, Default, Clone)]
pub struct LineLexer {
    /// Letter-number words of a classic command (`X10` → `('X', 10.0)`); a bare
    /// letter (`G28 X`) has value NaN.
    pub words: Vec<(char, f64)>,
    /// `KEY=VALUE` argument ranges of an extended command.
    pub args: Vec<(Range<usize>, Range<usize>)>,
    /// Words of `M`/`T` commands that are not numbers (`M115 U3.11.0`) read as
    /// NaN instead of failing: for readers that act on motion (`G`) only.
    pub lenient_m_words: bool,
}

/// Marlin commands whose whole argument is free text (`M117 Printing...`).
const TEXT_COMMANDS: [u32; 7] = [23, 28, 30, 32, 117, 118, 928];

fn trim(raw: &[u8], mut r: Range<usize>) -> Range<usize> {
    while r.start < r.end && raw[r.start].is_ascii_whitespace() {
        r.start += 1;
    }
    while r.end > r.start && raw[r.end - 1].is_ascii_whitespace() {
        r.end -= 1;
    }
    r
}

/// Next whitespace-separated token in `raw[*at..end]`.
fn token(raw: &[u8], at: &mut usize, end: usize) -> Option<Range<usize>> {
    while *at < end && raw[*at].is_ascii_whitespace() {
        *at += 1;
    }
    if *at >= end {
        return None;
    }
    let start = *at;
    while *at < end && !raw[*at].is_ascii_whitespace() {
        *at += 1;
    }
    Some(start..*at)
}

impl LineLexer {
    /// Lex one line (1-based `line` and `file` for errors). Words and arguments
    /// of the previous line are cleared.
    pub fn lex(&mut self, raw: &[u8], line: usize, file: &str) -> Result<Lexed, DatasetError> {
        self.words.clear();
        self.args.clear();
        // Code ends at a comment `;` or a RepRap checksum `*45`, whichever is first.
        let (code_end, semi) = match memchr::memchr2(b';', b'*', raw) {
            Some(i) if raw[i] == b';' => (i, Some(i)),
            Some(i) => (i, memchr::memchr(b';', &raw[i..]).map(|j| i + j)),
            None => (raw.len(), None),
        };
        let comment = semi.map(|i| trim(raw, i + 1..raw.len()));
        // Only a line with a `"` can hold a string argument.
        let quoted = memchr::memchr(b'"', &raw[..code_end]).is_some();
        let mut at = 0;
        let mut head = token(raw, &mut at, code_end);
        // Strip a RepRap line number `N123`.
        if let Some(t) = &head {
            let b = &raw[t.clone()];
            if b.len() > 1 && (b[0] == b'N' || b[0] == b'n') && b[1..].iter().all(u8::is_ascii_digit) {
                head = token(raw, &mut at, code_end);
            }
        }
        let Some(name) = head else {
            return Ok(Lexed { head: None, comment });
        };
        let nb = &raw[name.clone()];
        let letter = nb[0].to_ascii_uppercase();
        let classic = nb.len() >= 2 && matches!(letter, b'G' | b'M' | b'T') && nb[1..].iter().all(|c| c.is_ascii_digit() || *c == b'.');
        let code = if classic && nb[1..].iter().all(u8::is_ascii_digit) && nb.len() <= 10 {
            Some((letter, nb[1..].iter().fold(0u32, |acc, d| acc * 10 + u32::from(d - b'0'))))
        } else {
            None
        };
        if matches!(code, Some((b'M', n)) if TEXT_COMMANDS.contains(&n)) {
            return Ok(Lexed { head: Some(Head { name, code, classic }), comment });
        }
        let lenient = self.lenient_m_words && letter != b'G';
        while let Some(t) = token(raw, &mut at, code_end) {
            let tb = &raw[t.clone()];
            // A quoted string value (`M862.3 P "MK3S"`, `M1000 S"a b"`, `NAME="a b"`):
            // it may hold spaces; it is no number, so its word reads NaN.
            let quote = if quoted { tb.iter().position(|&b| b == b'"').filter(|&q| q <= 1 || tb[q - 1] == b'=') } else { None };
            if let Some(q) = quote {
                let open = t.start + q;
                let close = raw[open + 1..code_end].iter().position(|&b| b == b'"').map(|i| open + 1 + i);
                let Some(close) = close else {
                    return Err(DatasetError::parse(file, line, &name_str(nb), "unclosed `\"` in a string argument"));
                };
                at = close + 1;
                if q >= 1 && tb[q - 1] == b'=' && !classic {
                    self.args.push((t.start..open - 1, open + 1..close));
                } else if q == 1 && classic {
                    self.words.push((char::from(tb[0].to_ascii_uppercase()), f64::NAN));
                }
                continue;
            }
            if classic {
                let l = tb[0];
                if !l.is_ascii_alphabetic() && lenient {
                    continue;
                }
                if !l.is_ascii_alphabetic() {
                    let msg = format!("word `{}` does not start with a letter", String::from_utf8_lossy(tb));
                    return Err(DatasetError::parse(file, line, &name_str(nb), msg));
                }
                let l = char::from(l.to_ascii_uppercase());
                let value = if tb.len() == 1 {
                    f64::NAN
                } else if lenient {
                    parse_number(&tb[1..]).unwrap_or(f64::NAN)
                } else {
                    parse_number(&tb[1..])
                        .ok_or_else(|| DatasetError::parse(file, line, &l.to_string(), format!("`{}` is not a number", String::from_utf8_lossy(&tb[1..]))))?
                };
                self.words.push((l, value));
            } else if let Some(eq) = tb.iter().position(|&b| b == b'=') {
                self.args.push((t.start..t.start + eq, t.start + eq + 1..t.end));
            } else {
                let msg = format!("argument `{}` is not KEY=VALUE", String::from_utf8_lossy(tb));
                return Err(DatasetError::parse(file, line, &name_str(nb), msg));
            }
        }
        Ok(Lexed { head: Some(Head { name, code, classic }), comment })
    }

    /// Value of word `letter` (upper case) of the last lexed line.
    pub fn word(&self, letter: char) -> Option<f64> {
        self.words.iter().find(|(l, _)| *l == letter).map(|(_, v)| *v)
    }
}

fn name_str(b: &[u8]) -> String {
    String::from_utf8_lossy(b).to_ascii_uppercase()
}

/// Parse a finite decimal number. Plain decimals of up to 19 digits take
/// Clinger's exact fast path (Clinger 1990, "How to read floating point numbers
/// accurately", §3): an integer below 2⁵³ divided by an exact power of ten is
/// correctly rounded by one IEEE division. Everything else goes to `str::parse`.
pub fn parse_number(b: &[u8]) -> Option<f64> {
    const POW10: [f64; 23] = [1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22];
    let (neg, digits) = match b.first() {
        Some(b'-') => (true, &b[1..]),
        Some(b'+') => (false, &b[1..]),
        _ => (false, b),
    };
    let mut mantissa: u64 = 0;
    let mut n_digits = 0usize;
    let mut frac: Option<usize> = None;
    let mut fast = !digits.is_empty() && digits.len() <= 20;
    if fast {
        for &c in digits {
            match c {
                b'0'..=b'9' => {
                    mantissa = mantissa.wrapping_mul(10).wrapping_add(u64::from(c - b'0'));
                    n_digits += 1;
                    if let Some(f) = frac.as_mut() {
                        *f += 1;
                    }
                }
                b'.' if frac.is_none() => frac = Some(0),
                _ => {
                    fast = false;
                    break;
                }
            }
        }
    }
    let k = frac.unwrap_or(0);
    if fast && n_digits > 0 && n_digits <= 19 && mantissa < (1u64 << 53) && k < POW10.len() {
        let v = mantissa as f64 / POW10[k];
        return Some(if neg { -v } else { v });
    }
    std::str::from_utf8(b).ok()?.parse::<f64>().ok().filter(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn quoted_string_arguments_are_skipped_and_unclosed_ones_located() {
        let mut lx = LineLexer::default();
        let l = lx.lex(br#"M862.3 P "MK3S" ; model check"#, 3, "a.gcode").expect("lexes");
        assert!(l.head.is_some() && l.comment.is_some());
        let l = lx.lex(br#"M1000 S"a b.gco" X1"#, 4, "a.gcode").expect("lexes");
        assert!(l.head.is_some());
        assert!(lx.word('S').is_some_and(f64::is_nan) && lx.word('X') == Some(1.0));
        lx.lex(br#"RESPOND MSG="two words" TYPE=echo"#, 5, "a.gcode").expect("extended quoted value");
        assert_eq!(lx.args.len(), 2);
        let e = lx.lex(br#"M1000 P"open"#, 9, "a.gcode").expect_err("unclosed");
        assert!(e.to_string().contains("a.gcode") && e.to_string().contains('9'), "{e}");
    }

    #[test]
    fn message_commands_take_free_text_and_lenient_m_words_read_nan() {
        let mut lx = LineLexer::default();
        lx.lex(b"M117 Printing... 50%", 1, "a.gcode").expect("free text");
        assert!(lx.words.is_empty());
        assert!(lx.lex(b"M115 U3.11.0", 2, "a.gcode").is_err(), "strict by default");
        lx.lenient_m_words = true;
        lx.lex(b"M115 U3.11.0", 2, "a.gcode").expect("lenient");
        assert!(lx.word('U').is_some_and(f64::is_nan));
        // Motion words stay strict: a bad coordinate is still named.
        let e = lx.lex(b"G1 X1.2.3", 3, "a.gcode").expect_err("strict G");
        assert!(e.to_string().contains("X"), "{e}");
    }

    #[test]
    fn fast_path_agrees_with_std_on_awkward_decimals() {
        for s in ["0.1", "-0.0", "123.456", "9007199254740991", "9007199254740993", ".5", "5.", "+2.50", "0.000001", "1e3", "12345678901234567890.1"] {
            assert_eq!(parse_number(s.as_bytes()).map(f64::to_bits), s.parse::<f64>().ok().map(f64::to_bits), "{s}");
        }
        assert_eq!(parse_number(b"."), None);
        assert_eq!(parse_number(b"-"), None);
        assert_eq!(parse_number(b"inf"), None);
        assert_eq!(parse_number(b"1.2.3"), None);
    }

    proptest! {
        #[test]
        fn parses_every_decimal_as_std_does(int in 0u64..10_000_000_000, frac in "[0-9]{0,12}", neg in any::<bool>()) {
            let s = format!("{}{int}.{frac}", if neg { "-" } else { "" });
            prop_assert_eq!(parse_number(s.as_bytes()).map(f64::to_bits), s.parse::<f64>().ok().map(f64::to_bits));
        }

        #[test]
        fn round_trips_every_f64_display(v in -1e6f64..1e6) {
            let s = format!("{v}");
            prop_assert_eq!(parse_number(s.as_bytes()), Some(v));
        }
    }
}
