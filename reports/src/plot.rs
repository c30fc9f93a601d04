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
        let err = |e: &dyn std::fmt::Display| ReportError::Plot { plot: self.title.clone(), message: e.to_string() };
        let ((x0, x1), (y0, y1)) = self.ranges();
        let mut svg = String::new();
        {
            let root = SVGBackend::with_string(&mut svg, (800, 500)).into_drawing_area();
            root.fill(&WHITE).map_err(|e| err(&e))?;
            let mut chart = ChartBuilder::on(&root)
                .caption(&self.title, ("sans-serif", 20))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(|e| err(&e))?;
            chart.configure_mesh().x_desc(&self.x_label).y_desc(&self.y_label).draw().map_err(|e| err(&e))?;
            let shade = RGBColor(255, 200, 120).mix(0.35).filled();
            chart
                .draw_series(self.bands.iter().filter(|(a, b)| a.is_finite() && b.is_finite()).map(|&(a, b)| Rectangle::new([(a, y0), (b, y1)], shade)))
                .map_err(|e| err(&e))?;
            for (i, s) in self.series.iter().enumerate() {
                let color = PALETTE[i % PALETTE.len()];
                let pts = s.points.iter().copied().filter(|(x, y)| x.is_finite() && y.is_finite());
                let anno = match s.style {
                    SeriesStyle::Line => chart.draw_series(LineSeries::new(pts, color.stroke_width(2))).map_err(|e| err(&e))?,
                    SeriesStyle::Points => chart.draw_series(pts.map(|p| Circle::new(p, 3, color.filled()))).map_err(|e| err(&e))?,
                    SeriesStyle::LinePoints => chart.draw_series(LineSeries::new(pts, color.stroke_width(2)).point_size(3)).map_err(|e| err(&e))?,
                };
                anno.label(s.name.clone()).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2)));
            }
            if self.series.len() > 1 {
                chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(|e| err(&e))?;
            }
            root.present().map_err(|e| err(&e))?;
        }
        Ok(svg)
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
        assert_eq!(svg.matches("<circle").count(), 4, "{svg}");
        let plain = LinePlot::new("t", "x", "y").line("arx", vec![(1.0, 90.0), (2.0, 95.0)]).to_svg().expect("svg");
        assert_eq!(plain.matches("<circle").count(), 0);
    }

    #[test]
    fn bands_are_drawn_as_filled_rectangles() {
        let plain = LinePlot::new("r", "t", "e").line("e", vec![(0.0, 0.0), (10.0, 1.0)]).to_svg().expect("svg");
        let shaded = LinePlot::new("r", "t", "e").line("e", vec![(0.0, 0.0), (10.0, 1.0)]).shaded(vec![(2.0, 4.0), (6.0, 7.0)]).to_svg().expect("svg");
        assert_eq!(shaded.matches("<rect").count(), plain.matches("<rect").count() + 2);
    }
}
