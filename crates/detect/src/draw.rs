//! Drawing detections on an image: a rectangle per box and a small label (class and score) in a
//! built-in 3x5 pixel font, so `stillpoint detect --draw` needs no font file.

use crate::Detection;
use stillpoint_image::Rgb8;

/// 3x5 glyphs, one row per byte, the three low bits left to right.
const GLYPHS: &[(char, [u8; 5])] = &[
    ('a', [0b010, 0b101, 0b111, 0b101, 0b101]),
    ('b', [0b110, 0b101, 0b110, 0b101, 0b110]),
    ('c', [0b011, 0b100, 0b100, 0b100, 0b011]),
    ('d', [0b110, 0b101, 0b101, 0b101, 0b110]),
    ('e', [0b111, 0b100, 0b110, 0b100, 0b111]),
    ('f', [0b111, 0b100, 0b110, 0b100, 0b100]),
    ('g', [0b011, 0b100, 0b101, 0b101, 0b011]),
    ('h', [0b101, 0b101, 0b111, 0b101, 0b101]),
    ('i', [0b111, 0b010, 0b010, 0b010, 0b111]),
    ('j', [0b001, 0b001, 0b001, 0b101, 0b010]),
    ('k', [0b101, 0b101, 0b110, 0b101, 0b101]),
    ('l', [0b100, 0b100, 0b100, 0b100, 0b111]),
    ('m', [0b101, 0b111, 0b111, 0b101, 0b101]),
    ('n', [0b110, 0b101, 0b101, 0b101, 0b101]),
    ('o', [0b010, 0b101, 0b101, 0b101, 0b010]),
    ('p', [0b110, 0b101, 0b110, 0b100, 0b100]),
    ('q', [0b010, 0b101, 0b101, 0b110, 0b011]),
    ('r', [0b110, 0b101, 0b110, 0b101, 0b101]),
    ('s', [0b011, 0b100, 0b010, 0b001, 0b110]),
    ('t', [0b111, 0b010, 0b010, 0b010, 0b010]),
    ('u', [0b101, 0b101, 0b101, 0b101, 0b111]),
    ('v', [0b101, 0b101, 0b101, 0b101, 0b010]),
    ('w', [0b101, 0b101, 0b111, 0b111, 0b101]),
    ('x', [0b101, 0b101, 0b010, 0b101, 0b101]),
    ('y', [0b101, 0b101, 0b010, 0b010, 0b010]),
    ('z', [0b111, 0b001, 0b010, 0b100, 0b111]),
    ('0', [0b111, 0b101, 0b101, 0b101, 0b111]),
    ('1', [0b010, 0b110, 0b010, 0b010, 0b111]),
    ('2', [0b110, 0b001, 0b010, 0b100, 0b111]),
    ('3', [0b110, 0b001, 0b010, 0b001, 0b110]),
    ('4', [0b101, 0b101, 0b111, 0b001, 0b001]),
    ('5', [0b111, 0b100, 0b110, 0b001, 0b110]),
    ('6', [0b011, 0b100, 0b111, 0b101, 0b111]),
    ('7', [0b111, 0b001, 0b010, 0b010, 0b010]),
    ('8', [0b111, 0b101, 0b111, 0b101, 0b111]),
    ('9', [0b111, 0b101, 0b111, 0b001, 0b110]),
    ('.', [0b000, 0b000, 0b000, 0b000, 0b010]),
    ('-', [0b000, 0b000, 0b111, 0b000, 0b000]),
];

/// Pixel scale of the label font.
const FONT_SCALE: usize = 2;

/// A distinct colour per class (golden-ratio hue walk).
pub fn class_colour(class_id: u16) -> [u8; 3] {
    let hue = (class_id as f32 * 0.618_034).fract() * 6.0;
    let x = 1.0 - (hue % 2.0 - 1.0).abs();
    let (r, g, b) = match hue as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    [
        (r * 230.0) as u8 + 25,
        (g * 230.0) as u8 + 25,
        (b * 230.0) as u8 + 25,
    ]
}

fn fill(img: &mut Rgb8, x0: isize, y0: isize, x1: isize, y1: isize, colour: [u8; 3]) {
    let (w, h) = (img.width as isize, img.height as isize);
    for y in y0.max(0)..y1.min(h) {
        for x in x0.max(0)..x1.min(w) {
            img.set(x as usize, y as usize, colour);
        }
    }
}

/// Draw `text` (lower-case letters, digits, '.', '-'; others are blanks) with its top-left at
/// (x, y) on a filled background.
pub fn draw_text(img: &mut Rgb8, x: isize, y: isize, text: &str, fg: [u8; 3], bg: [u8; 3]) {
    let s = FONT_SCALE as isize;
    let advance = 4 * s;
    let width = text.chars().count() as isize * advance + s;
    fill(img, x, y, x + width, y + 7 * s, bg);
    for (i, ch) in text.chars().enumerate() {
        let Some((_, rows)) = GLYPHS.iter().find(|(c, _)| *c == ch.to_ascii_lowercase()) else {
            continue;
        };
        let gx = x + s + i as isize * advance;
        for (r, bits) in rows.iter().enumerate() {
            for c in 0..3 {
                if bits & (0b100 >> c) != 0 {
                    let px = gx + c as isize * s;
                    let py = y + s + r as isize * s;
                    fill(img, px, py, px + s, py + s, fg);
                }
            }
        }
    }
}

/// Draw each detection as a 2-pixel rectangle in its class colour with a "name score" label
/// above it (inside the box when there is no room above).
pub fn draw_detections(img: &mut Rgb8, dets: &[Detection]) {
    for d in dets {
        let label = format!("{} {:.2}", d.class_name(), d.score);
        draw_box(img, &d.bbox, class_colour(d.class_id), &label);
    }
}

/// Draw `bbox` as a 2-pixel rectangle in `colour` with `label` above it (inside the box when
/// there is no room above; no label when empty).
pub fn draw_box(img: &mut Rgb8, bbox: &crate::BBox, colour: [u8; 3], label: &str) {
    let (x1, y1) = (bbox.x1.round() as isize, bbox.y1.round() as isize);
    let (x2, y2) = (bbox.x2.round() as isize, bbox.y2.round() as isize);
    fill(img, x1, y1, x2, y1 + 2, colour);
    fill(img, x1, y2 - 2, x2, y2, colour);
    fill(img, x1, y1, x1 + 2, y2, colour);
    fill(img, x2 - 2, y1, x2, y2, colour);
    if !label.is_empty() {
        let label_h = 7 * FONT_SCALE as isize;
        let ly = if y1 >= label_h { y1 - label_h } else { y1 + 2 };
        draw_text(img, x1, ly, label, [0, 0, 0], colour);
    }
}

/// Draw a filled square of side `2 * radius + 1` centred on (x, y), clipped to the image.
pub fn draw_dot(img: &mut Rgb8, x: f32, y: f32, radius: isize, colour: [u8; 3]) {
    let (cx, cy) = (x.round() as isize, y.round() as isize);
    fill(
        img,
        cx - radius,
        cy - radius,
        cx + radius + 1,
        cy + radius + 1,
        colour,
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::BBox;

    #[test]
    fn draws_box_edges_and_label_and_survives_boxes_off_the_image() {
        let mut img = Rgb8::new(100, 80, [0, 0, 0]);
        let dets = [
            Detection {
                class_id: 0,
                score: 0.88,
                bbox: BBox::new(20.0, 30.0, 60.0, 70.0),
            },
            Detection {
                class_id: 62,
                score: 0.5,
                bbox: BBox::new(-50.0, -50.0, 500.0, 500.0),
            },
        ];
        draw_detections(&mut img, &dets);
        let colour = class_colour(0);
        assert_eq!(img.get(40, 30), colour);
        assert_eq!(img.get(20, 50), colour);
        assert_eq!(img.get(40, 50), [0, 0, 0]); // inside stays untouched
        // The label sits above the box and has dark text pixels on the colour.
        let label: Vec<[u8; 3]> = (16..30)
            .flat_map(|y| (20..60).map(move |x| (x, y)))
            .map(|(x, y)| img.get(x, y))
            .collect();
        assert!(label.contains(&colour) && label.contains(&[0, 0, 0]));
    }

    #[test]
    fn every_glyph_is_distinct() {
        for (i, a) in GLYPHS.iter().enumerate() {
            for b in &GLYPHS[i + 1..] {
                assert_ne!(a.1, b.1, "{} and {} look the same", a.0, b.0);
            }
        }
    }
}
