//! A small scatter plot (error against time, log x-axis) drawn straight into an RGB image with
//! a built-in 5×7 bitmap font, so the report needs no plotting or font dependency.

use crate::error::{EvalError, Result};
use image::{Rgb, RgbImage};
use std::path::Path;

/// One marker.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    /// Legend text (drawn upper-case; characters outside the font become `?`).
    pub label: String,
    /// x value (> 0: the axis is logarithmic).
    pub x: f64,
    /// y value.
    pub y: f64,
}

/// Axis titles and the plot title.
#[derive(Debug, Clone, PartialEq)]
pub struct Labels {
    /// Title above the plot.
    pub title: String,
    /// x-axis title.
    pub x: String,
    /// y-axis title.
    pub y: String,
}

const WIDTH: u32 = 1500;
const HEIGHT: u32 = 800;
const LEFT: i64 = 100;
const RIGHT: i64 = 880;
const TOP: i64 = 70;
const BOTTOM: i64 = 700;
const SCALE: i64 = 2;
const ADVANCE: i64 = 6 * SCALE;
const BG: Rgb<u8> = Rgb([255, 255, 255]);
const INK: Rgb<u8> = Rgb([20, 20, 20]);
const GRID: Rgb<u8> = Rgb([225, 225, 225]);

/// Distinct marker colours (Tableau 10, then darker variants); cycled past 20 points.
const PALETTE: [[u8; 3]; 20] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
    [16, 60, 90],
    [128, 64, 7],
    [22, 80, 22],
    [107, 20, 20],
    [74, 52, 95],
    [70, 43, 38],
    [114, 60, 97],
    [60, 60, 60],
    [94, 95, 17],
    [12, 95, 104],
];

/// The marker colour of point `k`.
pub fn colour(k: usize) -> [u8; 3] {
    PALETTE[k % PALETTE.len()]
}

/// 5×7 glyph rows (bit 4 = leftmost column).
fn glyph(c: char) -> [u8; 7] {
    match c {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        'A' => [0x0E, 0x11, 0x11, 0x11, 0x1F, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        ' ' => [0; 7],
        '.' => [0, 0, 0, 0, 0, 0x0C, 0x0C],
        ',' => [0, 0, 0, 0, 0x0C, 0x04, 0x08],
        '-' => [0, 0, 0, 0x1F, 0, 0, 0],
        '+' => [0, 0x04, 0x04, 0x1F, 0x04, 0x04, 0],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '/' => [0, 0x01, 0x02, 0x04, 0x08, 0x10, 0],
        ':' => [0, 0x0C, 0x0C, 0, 0x0C, 0x0C, 0],
        '=' => [0, 0, 0x1F, 0, 0x1F, 0, 0],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        '_' => [0, 0, 0, 0, 0, 0, 0x1F],
        '[' => [0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E],
        ']' => [0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E],
        '#' => [0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A],
        '*' => [0, 0x04, 0x15, 0x0E, 0x15, 0x04, 0],
        '≤' => [0x02, 0x04, 0x08, 0x04, 0x02, 0, 0x0E],
        '≥' => [0x08, 0x04, 0x02, 0x04, 0x08, 0, 0x0E],
        '°' => [0x0C, 0x12, 0x12, 0x0C, 0, 0, 0],
        _ => UNKNOWN,
    }
}

/// The glyph of a character the font lacks: a question mark.
const UNKNOWN: [u8; 7] = [0x0E, 0x11, 0x01, 0x02, 0x04, 0, 0x04];

/// Maps text to the font's repertoire: upper case, a few typographic characters replaced.
fn fold(text: &str) -> String {
    text.chars()
        .map(|c| match c {
            '·' | '—' | '–' | '→' => '-',
            '×' => 'X',
            '²' => '2',
            'µ' => 'U',
            c => c.to_ascii_uppercase(),
        })
        .collect()
}

/// Pixel width of `text` in the plot's font.
pub fn text_width(text: &str) -> i64 {
    fold(text).chars().count() as i64 * ADVANCE
}

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && x < i64::from(img.width()) && y < i64::from(img.height()) {
        img.put_pixel(x as u32, y as u32, c);
    }
}

/// Draws `text` with its top-left corner at (x, y).
pub fn draw_text(img: &mut RgbImage, x: i64, y: i64, text: &str, c: Rgb<u8>) {
    for (k, ch) in fold(text).chars().enumerate() {
        let g = glyph(ch);
        for (row, bits) in g.iter().enumerate() {
            for col in 0..5 {
                if bits & (0x10 >> col) != 0 {
                    for dy in 0..SCALE {
                        for dx in 0..SCALE {
                            put(
                                img,
                                x + k as i64 * ADVANCE + col * SCALE + dx,
                                y + row as i64 * SCALE + dy,
                                c,
                            );
                        }
                    }
                }
            }
        }
    }
}

fn hline(img: &mut RgbImage, x0: i64, x1: i64, y: i64, c: Rgb<u8>) {
    for x in x0..=x1 {
        put(img, x, y, c);
    }
}

fn vline(img: &mut RgbImage, x: i64, y0: i64, y1: i64, c: Rgb<u8>) {
    for y in y0..=y1 {
        put(img, x, y, c);
    }
}

fn disc(img: &mut RgbImage, cx: i64, cy: i64, r: i64, c: Rgb<u8>) {
    for dy in -r - 1..=r + 1 {
        for dx in -r - 1..=r + 1 {
            let d2 = dx * dx + dy * dy;
            if d2 <= r * r {
                put(img, cx + dx, cy + dy, c);
            } else if d2 <= (r + 1) * (r + 1) {
                put(img, cx + dx, cy + dy, INK);
            }
        }
    }
}

/// A tick label for 10^k.
fn decade_label(k: i32) -> String {
    if (0..=4).contains(&k) {
        format!("{}", 10f64.powi(k) as i64)
    } else if (-3..0).contains(&k) {
        format!("{:.*}", (-k) as usize, 10f64.powi(k))
    } else {
        format!("1E{k}")
    }
}

/// "Nice" upper bound and step for a linear axis from 0 to at least `max`.
fn nice_axis(max: f64) -> (f64, f64) {
    let max = if max > 0.0 && max.is_finite() {
        max
    } else {
        1.0
    };
    let raw = max / 5.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| s * 5.0 >= max)
        .unwrap_or(10.0 * mag);
    ((max / step).ceil() * step, step)
}

/// Draws the scatter plot: x logarithmic (decades), y linear from 0, one colour per point,
/// each marker numbered 1.. and listed in the legend on the right.
pub fn scatter(points: &[Point], labels: &Labels) -> Result<RgbImage> {
    let xs: Vec<f64> = points
        .iter()
        .map(|p| p.x)
        .filter(|x| *x > 0.0 && x.is_finite())
        .collect();
    if xs.is_empty() {
        return Err(EvalError::Plot("no point with a positive finite x".into()));
    }
    let lo = xs
        .iter()
        .cloned()
        .fold(f64::INFINITY, f64::min)
        .log10()
        .floor() as i32;
    let mut hi = xs.iter().cloned().fold(0.0, f64::max).log10().ceil() as i32;
    if hi <= lo {
        hi = lo + 1;
    }
    let ymax = points
        .iter()
        .map(|p| p.y)
        .filter(|y| y.is_finite())
        .fold(0.0, f64::max);
    let (ytop, ystep) = nice_axis(ymax * 1.05);
    let mut img = RgbImage::from_pixel(WIDTH, HEIGHT, BG);
    let px = |x: f64| {
        let t = (x.log10() - f64::from(lo)) / f64::from(hi - lo);
        LEFT + (t * (RIGHT - LEFT) as f64).round() as i64
    };
    let py = |y: f64| BOTTOM - ((y / ytop) * (BOTTOM - TOP) as f64).round() as i64;
    // Grid and ticks.
    for k in lo..=hi {
        let x = px(10f64.powi(k));
        vline(&mut img, x, TOP, BOTTOM, GRID);
        vline(&mut img, x, BOTTOM, BOTTOM + 6, INK);
        let l = decade_label(k);
        draw_text(&mut img, x - text_width(&l) / 2, BOTTOM + 12, &l, INK);
        if k < hi {
            for m in 2..10 {
                let xm = px(f64::from(m) * 10f64.powi(k));
                vline(&mut img, xm, BOTTOM, BOTTOM + 3, INK);
            }
        }
    }
    let ticks = (ytop / ystep).round() as i64;
    let decimals = if ystep >= 1.0 {
        0
    } else {
        (-ystep.log10().floor()) as usize + 1
    };
    for t in 0..=ticks {
        let v = t as f64 * ystep;
        let y = py(v);
        hline(&mut img, LEFT, RIGHT, y, GRID);
        hline(&mut img, LEFT - 6, LEFT, y, INK);
        let l = format!("{v:.decimals$}");
        draw_text(&mut img, LEFT - 10 - text_width(&l), y - 7, &l, INK);
    }
    hline(&mut img, LEFT, RIGHT, BOTTOM, INK);
    vline(&mut img, LEFT, TOP, BOTTOM, INK);
    draw_text(&mut img, LEFT, 14, &labels.title, INK);
    draw_text(&mut img, LEFT - 60, TOP - 28, &labels.y, INK);
    let xl = &labels.x;
    draw_text(
        &mut img,
        (LEFT + RIGHT) / 2 - text_width(xl) / 2,
        BOTTOM + 44,
        xl,
        INK,
    );
    // Markers, then their numbers, then the legend.
    for (k, p) in points.iter().enumerate() {
        if !(p.x > 0.0 && p.x.is_finite() && p.y.is_finite()) {
            continue;
        }
        let (x, y) = (px(p.x), py(p.y));
        disc(&mut img, x, y, 6, Rgb(colour(k)));
        draw_text(&mut img, x + 10, y - 16, &format!("{}", k + 1), INK);
    }
    let lx = RIGHT + 40;
    for (k, p) in points.iter().enumerate() {
        let y = TOP + k as i64 * 26;
        disc(&mut img, lx, y + 7, 6, Rgb(colour(k)));
        draw_text(&mut img, lx + 14, y, &format!("{} {}", k + 1, p.label), INK);
    }
    Ok(img)
}

/// Encodes `img` as PNG at `path`.
pub fn save_png(img: &RgbImage, path: &Path) -> Result<()> {
    img.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| EvalError::Plot(format!("{}: {e}", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pt(label: &str, x: f64, y: f64) -> Point {
        Point {
            label: label.into(),
            x,
            y,
        }
    }

    fn labels() -> Labels {
        Labels {
            title: "t".into(),
            x: "x".into(),
            y: "y".into(),
        }
    }

    #[test]
    fn markers_land_in_their_colours_at_log_positions() {
        let pts = [pt("a", 0.1, 0.02), pt("b", 1000.0, 0.1)];
        let img = scatter(&pts, &labels()).unwrap_or_else(|e| panic!("{e}"));
        // Decades 0.1 .. 1000: the first point is at the left edge, the second at the right.
        let (ytop, _) = nice_axis(0.1 * 1.05);
        let y0 = BOTTOM - ((0.02 / ytop) * (BOTTOM - TOP) as f64).round() as i64;
        assert_eq!(img.get_pixel(LEFT as u32, y0 as u32).0, colour(0));
        let y1 = BOTTOM - ((0.1 / ytop) * (BOTTOM - TOP) as f64).round() as i64;
        assert_eq!(img.get_pixel(RIGHT as u32, y1 as u32).0, colour(1));
    }

    #[test]
    fn no_positive_x_is_an_error() {
        assert!(scatter(&[pt("a", 0.0, 1.0)], &labels()).is_err());
    }

    #[test]
    fn text_is_drawn_with_the_bitmap_font() {
        let mut img = RgbImage::from_pixel(40, 20, BG);
        draw_text(&mut img, 0, 0, "1", INK);
        // '1' row 0 is 0x04: only column 2 is set.
        assert_eq!(*img.get_pixel(4, 0), INK);
        assert_eq!(*img.get_pixel(0, 0), BG);
        assert_eq!(text_width("ab·"), 3 * ADVANCE);
    }

    #[test]
    fn every_character_of_the_report_labels_has_a_glyph() {
        // The report's method names, specialisations and axis titles (report.rs, methods.rs).
        let text =
            "default · CPU fast · f32 · ≤ 1° per node (ND_enc once) 64² × 8 µs ≥ — – → [#*%]:/=_";
        let unknown: Vec<char> = fold(text)
            .chars()
            .filter(|&c| glyph(c) == UNKNOWN)
            .collect();
        assert!(unknown.is_empty(), "no glyph for {unknown:?}");
    }

    #[test]
    fn nice_axes_cover_the_maximum() {
        for m in [0.013, 0.07, 0.1211, 0.9, 3.0] {
            let (top, step) = nice_axis(m);
            assert!(top >= m && top <= m * 2.6, "{m}: {top}");
            assert!((top / step).round() <= 6.0);
        }
        assert_eq!(decade_label(-2), "0.01");
        assert_eq!(decade_label(3), "1000");
        assert_eq!(decade_label(6), "1E6");
    }
}
