//! Draws detections on an image: a coloured outline per box and a tag with
//! the class name and score in a built-in 5×7 pixel font (ASCII letters,
//! digits and a little punctuation; letters are drawn upper-case).

use image::{Rgb, RgbImage};

use crate::classes::Labeled;

const PALETTE: [[u8; 3]; 8] = [
    [255, 56, 56],
    [72, 249, 10],
    [0, 194, 255],
    [255, 157, 151],
    [255, 178, 29],
    [207, 210, 49],
    [132, 56, 255],
    [255, 55, 199],
];

/// The colour of a label (stable across runs).
fn colour(label: &str) -> Rgb<u8> {
    let h = label.bytes().fold(2166136261u32, |h, b| (h ^ b as u32).wrapping_mul(16777619));
    Rgb(PALETTE[h as usize % PALETTE.len()])
}

/// Rows of a 5×7 glyph, bit 4 the leftmost pixel.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        ' ' => [0; 7],
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
        '.' => [0, 0, 0, 0, 0, 0x0C, 0x0C],
        '-' => [0, 0, 0, 0x1F, 0, 0, 0],
        ':' => [0, 0x0C, 0x0C, 0, 0x0C, 0x0C, 0],
        '_' => [0, 0, 0, 0, 0, 0, 0x1F],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '/' => [0, 0x01, 0x02, 0x04, 0x08, 0x10, 0],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        _ => [0x0E, 0x11, 0x01, 0x02, 0x04, 0, 0x04],
    }
}

fn fill(img: &mut RgbImage, x0: i64, y0: i64, x1: i64, y1: i64, c: Rgb<u8>) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    for y in y0.max(0)..y1.min(h) {
        for x in x0.max(0)..x1.min(w) {
            img.put_pixel(x as u32, y as u32, c);
        }
    }
}

/// Draws `text` with its top-left corner at (x, y), each font pixel `scale`×`scale`.
fn text(img: &mut RgbImage, x: i64, y: i64, scale: i64, s: &str, c: Rgb<u8>) {
    for (i, ch) in s.chars().enumerate() {
        let gx = x + i as i64 * 6 * scale;
        for (row, bits) in glyph(ch).iter().enumerate() {
            for col in 0..5 {
                if bits & (0x10 >> col) != 0 {
                    let (px, py) = (gx + col * scale, y + row as i64 * scale);
                    fill(img, px, py, px + scale, py + scale, c);
                }
            }
        }
    }
}

/// Draws every detection on `img`: outline, and a tag "<label> <score>" above
/// the box (inside it when the box touches the top edge).
pub fn draw(img: &mut RgbImage, detections: &[Labeled]) {
    let side = img.width().min(img.height()) as i64;
    let thick = (side / 250).max(2);
    let scale = (side / 300).max(1);
    for l in detections {
        let d = &l.detection;
        let c = colour(&l.label);
        let (x0, y0, x1, y1) =
            (d.x_min.round() as i64, d.y_min.round() as i64, d.x_max.round() as i64, d.y_max.round() as i64);
        fill(img, x0, y0, x1, y0 + thick, c);
        fill(img, x0, y1 - thick, x1, y1, c);
        fill(img, x0, y0, x0 + thick, y1, c);
        fill(img, x1 - thick, y0, x1, y1, c);
        let tag = format!("{} {:.2}", l.label, d.score);
        let (tw, th) = (tag.chars().count() as i64 * 6 * scale + scale, 9 * scale);
        let ty = if y0 - th >= 0 { y0 - th } else { y0 };
        fill(img, x0, ty, x0 + tw, ty + th, c);
        text(img, x0 + scale, ty + scale, scale, &tag, Rgb([0, 0, 0]));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detection::Detection;

    #[test]
    fn outlines_and_tags_land_where_the_box_is() {
        let mut img = RgbImage::from_pixel(100, 80, Rgb([255, 255, 255]));
        let d = Detection { x_min: 20.0, y_min: 30.0, x_max: 60.0, y_max: 70.0, class_id: 0, score: 0.5 };
        draw(&mut img, &[Labeled { detection: d, label: "person".into() }]);
        let c = colour("person");
        // Outline on all four sides, the inside untouched, the tag above the box.
        for (x, y) in [(40, 30), (40, 69), (20, 50), (59, 50)] {
            assert_eq!(*img.get_pixel(x, y), c, "({x}, {y})");
        }
        assert_eq!(*img.get_pixel(40, 50), Rgb([255, 255, 255]));
        assert!((21..29).any(|y| (20..60).any(|x| *img.get_pixel(x, y) == Rgb([0, 0, 0]))), "tag text");
        // Boxes partly outside the image are clipped, not a panic.
        let out = Detection { x_min: -10.0, y_min: -5.0, x_max: 500.0, y_max: 90.0, ..d };
        draw(&mut img, &[Labeled { detection: out, label: "?weird é".into() }]);
    }
}
