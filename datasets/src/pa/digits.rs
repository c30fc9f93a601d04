//! A seven-segment stroke font, so K_A labels can be extruded on the bed.

/// Segments of a digit cell of width `w` and height `h` as strokes
/// `((x0, y0), (x1, y1))` in cell coordinates (origin bottom left).
fn segment(seg: u8, w: f64, h: f64) -> ((f64, f64), (f64, f64)) {
    let m = h / 2.0;
    match seg {
        b'a' => ((0.0, h), (w, h)),
        b'b' => ((w, h), (w, m)),
        b'c' => ((w, m), (w, 0.0)),
        b'd' => ((w, 0.0), (0.0, 0.0)),
        b'e' => ((0.0, 0.0), (0.0, m)),
        b'f' => ((0.0, m), (0.0, h)),
        _ => ((0.0, m), (w, m)), // g
    }
}

/// Lit segments of a character, in a drawing order that chains strokes where possible.
fn segments_of(c: char) -> Option<&'static [u8]> {
    Some(match c {
        '0' => b"abcdef",
        '1' => b"bc",
        '2' => b"abged",
        '3' => b"abgcd",
        '4' => b"fgbc",
        '5' => b"afgcd",
        '6' => b"afedcg",
        '7' => b"abc",
        '8' => b"abcdefg",
        '9' => b"gfabcd",
        _ => return None,
    })
}

/// A straight stroke from one point to another, mm.
pub type Stroke = ((f64, f64), (f64, f64));

/// Strokes of `text` (digits and '.') starting at `(x, y)` with character height `h`;
/// returns the strokes and the text's width. Other characters are an error.
pub fn strokes(text: &str, x: f64, y: f64, h: f64) -> Result<(Vec<Stroke>, f64), char> {
    let w = h / 2.0;
    let gap = h / 4.0;
    let mut out = Vec::new();
    let mut cx = x;
    for c in text.chars() {
        if c == '.' {
            // a short dash on the baseline reads as a decimal point
            let d = (h / 6.0).max(0.3);
            out.push(((cx, y), (cx + d, y)));
            cx += d + gap;
            continue;
        }
        let segs = segments_of(c).ok_or(c)?;
        for &s in segs {
            let ((x0, y0), (x1, y1)) = segment(s, w, h);
            out.push(((cx + x0, y + y0), (cx + x1, y + y1)));
        }
        cx += w + gap;
    }
    Ok((out, (cx - x - gap).max(0.0)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eight_has_seven_strokes_and_width_adds_up() {
        let (s, w) = strokes("8.8", 0.0, 0.0, 4.0).unwrap_or_default();
        assert_eq!(s.len(), 7 + 1 + 7);
        // 2 + 1 (gap) + 0.667 (dot) + 1 (gap) + 2
        assert!((w - (2.0 + 1.0 + 4.0 / 6.0 + 1.0 + 2.0)).abs() < 1e-12);
        assert!(strokes("1a", 0.0, 0.0, 4.0).is_err());
    }
}
