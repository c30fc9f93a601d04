//! Line and scatter plots rendered to SVG with plotters (no system fonts needed).

use crate::ReportError;
use plotters::prelude::*;
use serde::{Deserialize, Serialize};

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum SeriesStyle {
    /// Connected line.
    Line,
    /// Unconnected markers.
    Points,
    /// Connected line with a marker at each point (readable for few points).
    LinePoints,
}

/// One named series of (x, y) points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Series {
    /// Legend label.
    pub name: String,
    /// Data points.
    pub points: Vec<(f64, f64)>,
    /// Line or markers.
    pub style: SeriesStyle,
}

/// An x–y plot of several series.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LinePlot {
    /// Title (also the Markdown alt text).
    pub title: String,
    /// x-axis label with unit.
    pub x_label: String,
    /// y-axis label with unit.
    pub y_label: String,
    /// Series drawn in order.
    pub series: Vec<Series>,
    /// x intervals shaded behind the series (e.g. disagreement windows).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub bands: Vec<(f64, f64)>,
}

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

impl LinePlot {
    /// An empty plot.
    pub fn new(title: impl Into<String>, x_label: impl Into<String>, y_label: impl Into<String>) -> Self {
        LinePlot { title: title.into(), x_label: x_label.into(), y_label: y_label.into(), series: Vec::new(), bands: Vec::new() }
    }
    /// Add a line series (builder style).
    pub fn line(mut self, name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        self.series.push(Series { name: name.into(), points, style: SeriesStyle::Line });
        self
    }
    /// Add a line series with a marker at each point (builder style).
    pub fn line_points(mut self, name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        self.series.push(Series { name: name.into(), points, style: SeriesStyle::LinePoints });
        self
    }
    /// Shade the x intervals `bands` behind the series (builder style).
    pub fn shaded(mut self, bands: Vec<(f64, f64)>) -> Self {
        self.bands.extend(bands);
        self
    }
    /// Add a marker series (builder style).
    pub fn points(mut self, name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        self.series.push(Series { name: name.into(), points, style: SeriesStyle::Points });
        self
    }

    fn ranges(&self) -> ((f64, f64), (f64, f64)) {
        let finite = self.series.iter().flat_map(|s| s.points.iter()).filter(|(x, y)| x.is_finite() && y.is_finite());
        let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
        for &(x, y) in finite {
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
        let pad = |a: f64, b: f64| {
            if !a.is_finite() {
                (0.0, 1.0)
            } else if a == b {
                (a - 0.5 * a.abs().max(1.0), b + 0.5 * b.abs().max(1.0))
            } else {
                let m = 0.05 * (b - a);
                (a - m, b + m)
            }
        };
        (pad(x0, x1), pad(y0, y1))
    }

    /// Render to an SVG document (800 × 500 px).
    pub fn to_svg(&self) -> Result<String, ReportError> {
        let mut svg = String::new();
        self.draw(SVGBackend::with_string(&mut svg, (WIDTH, HEIGHT)).into_drawing_area(), 1)?;
        Ok(svg)
    }

    /// Render to a PNG image (1600 × 1000 px: the SVG layout at twice the scale),
    /// text in the DejaVu Sans font shipped in `reports/fonts`.
    pub fn to_png(&self) -> Result<Vec<u8>, ReportError> {
        let (w, h) = (WIDTH * PNG_SCALE, HEIGHT * PNG_SCALE);
        let mut rgb = vec![0u8; (w * h * 3) as usize];
        self.draw(BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area(), PNG_SCALE)?;
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let err = |e: png::EncodingError| ReportError::Plot { plot: self.title.clone(), message: e.to_string() };
        let mut writer = enc.write_header().map_err(err)?;
        writer.write_image_data(&rgb).map_err(err)?;
        writer.finish().map_err(err)?;
        Ok(out)
    }

    /// Draw on any backend; sizes are multiplied by `scale`. With more than one
    /// series the legend sits in a panel right of the plot, never over the data.
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, plotters::coord::Shift>, scale: u32) -> Result<(), ReportError> {
        register_font();
        let err = |e: &dyn std::fmt::Display| ReportError::Plot { plot: self.title.clone(), message: e.to_string() };
        let s = scale as i32;
        let ((x0, x1), (y0, y1)) = self.ranges();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let legend = self.series.len() > 1;
        let (plot_area, legend_area) = root.split_horizontally(if legend { (WIDTH - LEGEND_W) * scale } else { WIDTH * scale });
        let mut chart = ChartBuilder::on(&plot_area)
            .caption(&self.title, (FONT, 20 * s))
            .margin(12 * s)
            .x_label_area_size(44 * s)
            .y_label_area_size(64 * s)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc(&self.x_label)
            .y_desc(&self.y_label)
            .label_style((FONT, 12 * s))
            .axis_desc_style((FONT, 14 * s))
            .draw()
            .map_err(|e| err(&e))?;
        let shade = RGBColor(255, 200, 120).mix(0.35).filled();
        chart
            .draw_series(self.bands.iter().filter(|(a, b)| a.is_finite() && b.is_finite()).map(|&(a, b)| Rectangle::new([(a, y0), (b, y1)], shade)))
            .map_err(|e| err(&e))?;
        let (stroke, marker) = (2 * scale, 3 * scale);
        for (i, series) in self.series.iter().enumerate() {
            let color = PALETTE[i % PALETTE.len()];
            let pts = series.points.iter().copied().filter(|(x, y)| x.is_finite() && y.is_finite());
            match series.style {
                SeriesStyle::Line => chart.draw_series(LineSeries::new(pts, color.stroke_width(stroke))).map_err(|e| err(&e))?,
                SeriesStyle::Points => chart.draw_series(pts.map(|p| Circle::new(p, marker, color.filled()))).map_err(|e| err(&e))?,
                SeriesStyle::LinePoints => chart.draw_series(LineSeries::new(pts, color.stroke_width(stroke)).point_size(marker)).map_err(|e| err(&e))?,
            };
        }
        if legend {
            let text = TextStyle::from((FONT, 13 * s).into_font()).color(&BLACK);
            for (i, series) in self.series.iter().enumerate() {
                let color = PALETTE[i % PALETTE.len()];
                let y = (48 + 22 * i as i32) * s;
                legend_area.draw(&PathElement::new(vec![(8 * s, y), (30 * s, y)], color.stroke_width(stroke))).map_err(|e| err(&e))?;
                if series.style != SeriesStyle::Line {
                    legend_area.draw(&Circle::new((19 * s, y), marker, color.filled())).map_err(|e| err(&e))?;
                }
                legend_area.draw_text(&legend_name(&series.name), &text, (36 * s, y - 7 * s)).map_err(|e| err(&e))?;
            }
        }
        root.present().map_err(|e| err(&e))?;
        Ok(())
    }
}

/// Plot size in SVG pixels, the legend panel's width, and the PNG scale.
const WIDTH: u32 = 800;
const HEIGHT: u32 = 500;
const LEGEND_W: u32 = 200;
const PNG_SCALE: u32 = 2;
/// The one font family of every plot, registered from the shipped file.
const FONT: &str = "sans-serif";

/// Register DejaVu Sans (shipped in `reports/fonts`, Bitstream Vera licence)
/// as the plots' font, once: no plot depends on the machine's fonts.
fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The bytes are a valid TrueType file checked in with the crate; a
        // failure here would show as missing text, caught by the PNG test.
        let _ = plotters::style::register_font(FONT, FontStyle::Normal, include_bytes!("../fonts/DejaVuSans.ttf"));
    });
}

/// A legend entry fits the panel: at most 26 characters, else cut with "…".
fn legend_name(name: &str) -> String {
    if name.chars().count() <= 26 {
        name.to_string()
    } else {
        name.chars().take(25).chain(std::iter::once('…')).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_points_marks_every_point_and_a_single_point_stays_visible() {
        let svg = LinePlot::new("Fit by order", "order", "fit %")
            .line_points("arx", vec![(1.0, 90.0), (2.0, 95.0), (3.0, 96.0)])
            .line_points("fopdt", vec![(1.0, 93.0)])
            .to_svg()
            .expect("svg");
        // 4 data points + one marker per legend entry (the legend shows the style).
        assert_eq!(svg.matches("<circle").count(), 6, "{svg}");
        let plain = LinePlot::new("t", "x", "y").line("arx", vec![(1.0, 90.0), (2.0, 95.0)]).to_svg().expect("svg");
        assert_eq!(plain.matches("<circle").count(), 0);
    }

    #[test]
    fn png_is_drawn_with_the_shipped_font_and_the_legend_beside_the_data() {
        let plot = LinePlot::new("Fit by order", "order", "fit %").line("arx", vec![(1.0, 90.0), (2.0, 95.0)]).line("fopdt", vec![(1.0, 93.0), (2.0, 91.0)]);
        let bytes = plot.to_png().expect("png");
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().expect("decodes");
        let mut rgb = vec![0; reader.output_buffer_size().expect("size")];
        let info = reader.next_frame(&mut rgb).expect("frame");
        assert_eq!((info.width, info.height), (1600, 1000));
        let dark = |x0: u32, x1: u32, y0: u32, y1: u32| {
            (y0..y1).flat_map(|y| (x0..x1).map(move |x| (x, y))).filter(|&(x, y)| rgb[3 * (y * 1600 + x) as usize] < 100).count()
        };
        // The legend panel (right 400 px) holds the two names drawn in black:
        // glyphs only appear when the shipped font was registered.
        assert!(dark(1200, 1600, 0, 300) > 200, "legend text missing");
        // The title is drawn above the plot area too.
        assert!(dark(0, 1200, 0, 60) > 200, "title text missing");
    }

    #[test]
    fn bands_are_drawn_as_filled_rectangles() {
        let plain = LinePlot::new("r", "t", "e").line("e", vec![(0.0, 0.0), (10.0, 1.0)]).to_svg().expect("svg");
        let shaded = LinePlot::new("r", "t", "e").line("e", vec![(0.0, 0.0), (10.0, 1.0)]).shaded(vec![(2.0, 4.0), (6.0, 7.0)]).to_svg().expect("svg");
        assert_eq!(shaded.matches("<rect").count(), plain.matches("<rect").count() + 2);
    }
}
