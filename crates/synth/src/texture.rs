//! Textures: mip-mapped RGBA images sampled with trilinear filtering, procedural generators that
//! give ORB corners at many scales without repeating patterns, and photo / cut-out loading.

use rand::Rng;
use rand_pcg::Pcg64Mcg;
use std::path::{Path, PathBuf};
use stillpoint_image::Rgb8;

/// One mip level, RGBA.
#[derive(Clone, Debug)]
pub struct Level {
    /// Width, texels.
    pub width: usize,
    /// Height, texels.
    pub height: usize,
    /// RGBA texels, row-major.
    pub data: Vec<[u8; 4]>,
}

/// A texture with its mip chain (level 0 full size, each next level half as large).
#[derive(Clone, Debug)]
pub struct Texture {
    /// Level 0 (full size) first, each next one half as large.
    pub levels: Vec<Level>,
    /// True when some texel is transparent (alpha-tested cut-outs).
    pub has_alpha: bool,
}

/// log2 of a positive normal float, exact at powers of two and linear in between (error < 0.09;
/// only the blend between mip levels depends on it, and libm's log2f was 6 % of the time).
#[inline]
fn fast_log2(x: f32) -> f32 {
    let bits = x.to_bits();
    let exponent = ((bits >> 23) & 0xff) as i32 - 127;
    let mantissa = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    exponent as f32 + (mantissa - 1.0)
}

impl Texture {
    /// Build from a level-0 image, computing the mip chain (alpha-weighted 2x2 box filter).
    pub fn from_level(base: Level) -> Texture {
        let has_alpha = base.data.iter().any(|p| p[3] < 255);
        let mut levels = vec![base];
        loop {
            let prev = levels.last().expect("at least one level");
            if prev.width <= 1 && prev.height <= 1 {
                break;
            }
            let (w, h) = ((prev.width / 2).max(1), (prev.height / 2).max(1));
            let mut data = Vec::with_capacity(w * h);
            for y in 0..h {
                for x in 0..w {
                    let mut acc = [0u32; 4];
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let sx = (2 * x + dx).min(prev.width - 1);
                        let sy = (2 * y + dy).min(prev.height - 1);
                        let p = prev.data[sy * prev.width + sx];
                        let a = p[3] as u32 + 1; // +1 keeps fully transparent texels' colour
                        for c in 0..3 {
                            acc[c] += p[c] as u32 * a;
                        }
                        acc[3] += a;
                    }
                    let asum = acc[3];
                    data.push([
                        (acc[0] / asum) as u8,
                        (acc[1] / asum) as u8,
                        (acc[2] / asum) as u8,
                        ((asum - 4) / 4) as u8,
                    ]);
                }
            }
            levels.push(Level {
                width: w,
                height: h,
                data,
            });
        }
        Texture { levels, has_alpha }
    }

    /// Bilinear sample of one level at texture coordinates (u, v) in [0, 1] (clamped).
    #[inline]
    fn bilinear(&self, level: usize, u: f32, v: f32) -> [f32; 4] {
        let l = &self.levels[level];
        let x = (u * l.width as f32 - 0.5).clamp(0.0, (l.width - 1) as f32);
        let y = (v * l.height as f32 - 0.5).clamp(0.0, (l.height - 1) as f32);
        let (x0, y0) = (x as usize, y as usize);
        let (x1, y1) = ((x0 + 1).min(l.width - 1), (y0 + 1).min(l.height - 1));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let p00 = l.data[y0 * l.width + x0];
        let p10 = l.data[y0 * l.width + x1];
        let p01 = l.data[y1 * l.width + x0];
        let p11 = l.data[y1 * l.width + x1];
        let mut out = [0.0f32; 4];
        for c in 0..4 {
            let top = p00[c] as f32 + (p10[c] as f32 - p00[c] as f32) * fx;
            let bot = p01[c] as f32 + (p11[c] as f32 - p01[c] as f32) * fx;
            out[c] = top + (bot - top) * fy;
        }
        out
    }

    /// Trilinear sample: `texels_per_pixel` is how many level-0 texels one pixel spans.
    #[inline]
    pub fn sample(&self, u: f32, v: f32, texels_per_pixel: f32) -> [f32; 4] {
        let lod = fast_log2(texels_per_pixel.max(1.0));
        let max = (self.levels.len() - 1) as f32;
        let lod = lod.min(max);
        let l0 = lod as usize;
        let f = lod - l0 as f32;
        let a = self.bilinear(l0, u, v);
        if f < 0.01 || l0 + 1 >= self.levels.len() {
            return a;
        }
        let b = self.bilinear(l0 + 1, u, v);
        [
            a[0] + (b[0] - a[0]) * f,
            a[1] + (b[1] - a[1]) * f,
            a[2] + (b[2] - a[2]) * f,
            a[3] + (b[3] - a[3]) * f,
        ]
    }

    /// Level-0 size.
    pub fn size(&self) -> (usize, usize) {
        (self.levels[0].width, self.levels[0].height)
    }
}

/// A float RGB canvas procedural textures are painted on.
pub struct Canvas {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// RGB in 0..1, row-major.
    pub data: Vec<[f32; 3]>,
}

/// What a procedural texture looks like.
#[derive(Clone, Copy, Debug)]
pub enum Style {
    /// Painted wall with posters, notes and marks.
    Wall([f32; 3]),
    /// Floor: mottled surface with scattered marks and rugs.
    Floor([f32; 3]),
    /// Wood or laminate with papers and objects on it.
    Wood([f32; 3]),
    /// Cloth in a colour, blotchy.
    Fabric([f32; 3]),
    /// Clothes: a plain colour with soft folds and a fine weave, no printed blobs (the blobs
    /// of `Fabric` made people look like upholstery to a detector).
    Cloth([f32; 3]),
    /// Skin with hair on top and a face at u = 0.5.
    Head([f32; 3], [f32; 3]),
    /// Skin.
    Skin([f32; 3]),
    /// A monitor: dark frame, bright windows with text.
    Screen,
    /// Cardboard with tape and labels.
    Cardboard,
    /// Plastic or metal in a colour, fine noise only.
    Plain([f32; 3]),
    /// A poster: blocks, circles and text.
    Poster,
    /// Book covers and spines.
    Books,
    /// Leaves.
    Leaves,
    /// Painted plaster (the living room's walls and ceiling): a plain colour with only very
    /// low-contrast smooth variation and a soft shading from top to bottom; no marks, so it
    /// gives ORB next to no corners.
    Paint([f32; 3]),
    /// Wall-to-wall carpet or matt floor: a plain colour with low-contrast smooth variation and
    /// a fine, faint pile.
    Carpet([f32; 3]),
    /// A rug in a colour with a border band of a second colour and a faint lozenge pattern, all
    /// low contrast.
    Rug([f32; 3], [f32; 3]),
    /// A framed painting (frame in the texture): soft sky, hills and a sun, mid contrast.
    Painting,
    /// Upholstery: a colour with soft folds and a faint weave.
    Upholstery([f32; 3]),
    /// A painted door or cabinet front: plain, with two faint recessed panels.
    Panel([f32; 3]),
    /// Wood grain without anything lying on it.
    Grain([f32; 3]),
    /// A checked (plaid) shirt: bands of the second colour crossing over the first, thin dark
    /// lines, soft folds (high contrast, like the shirt in TUM fr3/walking).
    Plaid([f32; 3], [f32; 3]),
    /// A loud printed shirt: flowers of saturated colours over a base colour.
    Floral([f32; 3]),
    /// Denim: diagonal twill, fading, seams with contrast stitching and pockets.
    Denim([f32; 3]),
    /// Camouflage trousers: blotches of four colours (as the shorts in TUM fr3/walking).
    Camo,
}

impl Canvas {
    /// A `width` x `height` canvas filled with colour `c`.
    pub fn new(width: usize, height: usize, c: [f32; 3]) -> Canvas {
        Canvas {
            width,
            height,
            data: vec![c; width * height],
        }
    }

    /// Multiply brightness by (1 + amp * value noise) with lattice spacing `cell` texels
    /// (`stretch` > 1 elongates the noise along x, for wood grain).
    pub fn value_noise(&mut self, rng: &mut Pcg64Mcg, cell: f32, amp: f32, stretch: f32) {
        let cx = cell * stretch;
        let gw = (self.width as f32 / cx) as usize + 3;
        let gh = (self.height as f32 / cell) as usize + 3;
        let lattice: Vec<f32> = (0..gw * gh).map(|_| rng.random_range(-1.0..1.0)).collect();
        let smooth = |t: f32| t * t * (3.0 - 2.0 * t);
        for y in 0..self.height {
            let gy = y as f32 / cell;
            let (iy, fy) = (gy as usize, smooth(gy.fract()));
            for x in 0..self.width {
                let gx = x as f32 / cx;
                let (ix, fx) = (gx as usize, smooth(gx.fract()));
                let a = lattice[iy * gw + ix];
                let b = lattice[iy * gw + ix + 1];
                let c = lattice[(iy + 1) * gw + ix];
                let d = lattice[(iy + 1) * gw + ix + 1];
                let n = a + (b - a) * fx + (c - a + (a - b - c + d) * fx) * fy;
                let m = 1.0 + amp * n;
                let p = &mut self.data[y * self.width + x];
                for ch in p.iter_mut() {
                    *ch *= m;
                }
            }
        }
    }

    /// Fractal noise: octaves from `coarse` texels down to 2 texels, amplitude shrinking with scale.
    pub fn fbm(&mut self, rng: &mut Pcg64Mcg, coarse: f32, amp: f32) {
        let mut cell = coarse;
        let mut a = amp;
        while cell >= 2.0 {
            self.value_noise(rng, cell, a, 1.0);
            cell /= 2.0;
            a *= 0.75;
        }
    }

    /// Fill an axis-aligned rectangle (texel coordinates), blending with `alpha`.
    pub fn rect(&mut self, x0: f32, y0: f32, x1: f32, y1: f32, c: [f32; 3], alpha: f32) {
        let xa = x0.max(0.0) as usize;
        let ya = y0.max(0.0) as usize;
        let xb = (x1.min(self.width as f32).max(0.0)) as usize;
        let yb = (y1.min(self.height as f32).max(0.0)) as usize;
        for y in ya..yb {
            for x in xa..xb {
                blend(&mut self.data[y * self.width + x], c, alpha);
            }
        }
    }

    /// Fill an ellipse.
    pub fn ellipse(&mut self, cx: f32, cy: f32, rx: f32, ry: f32, c: [f32; 3], alpha: f32) {
        let ya = (cy - ry).max(0.0) as usize;
        let yb = ((cy + ry).min(self.height as f32 - 1.0).max(0.0)) as usize;
        let xa = (cx - rx).max(0.0) as usize;
        let xb = ((cx + rx).min(self.width as f32 - 1.0).max(0.0)) as usize;
        for y in ya..=yb {
            for x in xa..=xb {
                let dx = (x as f32 - cx) / rx.max(0.5);
                let dy = (y as f32 - cy) / ry.max(0.5);
                if dx * dx + dy * dy <= 1.0 {
                    blend(&mut self.data[y * self.width + x], c, alpha);
                }
            }
        }
    }

    /// A straight stroke of `thick` texels.
    pub fn line(&mut self, a: [f32; 2], b: [f32; 2], thick: f32, c: [f32; 3]) {
        let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
        let n = (len * 1.5) as usize + 1;
        for i in 0..=n {
            let t = i as f32 / n as f32;
            let x = a[0] + (b[0] - a[0]) * t;
            let y = a[1] + (b[1] - a[1]) * t;
            self.ellipse(x, y, thick * 0.5, thick * 0.5, c, 1.0);
        }
    }

    /// Lines of "text": dashes of random lengths in rows, inside a rectangle.
    pub fn text(&mut self, rng: &mut Pcg64Mcg, r: [f32; 4], glyph: f32, c: [f32; 3]) {
        let mut y = r[1] + glyph;
        while y + glyph < r[3] {
            let mut x = r[0] + rng.random_range(0.0..glyph * 2.0);
            let end = r[2] - rng.random_range(0.0..(r[2] - r[0]) * 0.4);
            while x < end {
                let word = glyph * rng.random_range(1.0..6.0f32);
                // letters: small blocks with gaps so FAST sees corners inside words
                let mut lx = x;
                while lx < (x + word).min(end) {
                    let lw = glyph * rng.random_range(0.4..0.9f32);
                    let lh = glyph * rng.random_range(0.6..1.0f32);
                    self.rect(lx, y - lh, lx + lw, y, c, 1.0);
                    lx += lw + glyph * 0.25;
                }
                x += word + glyph;
            }
            y += glyph * rng.random_range(1.6..2.4f32);
        }
    }

    /// Random shapes with sizes spread log-uniformly between `min` and `max` texels.
    pub fn scatter(
        &mut self,
        rng: &mut Pcg64Mcg,
        count: usize,
        min: f32,
        max: f32,
        dark: bool,
        notes: bool,
    ) {
        for _ in 0..count {
            let s = (min.ln() + rng.random_range(0.0..1.0f32) * (max.ln() - min.ln())).exp();
            let x = rng.random_range(0.0..self.width as f32);
            let y = rng.random_range(0.0..self.height as f32);
            let c = if dark {
                let g = rng.random_range(0.15..0.55f32);
                [
                    g,
                    g * rng.random_range(0.8..1.2),
                    g * rng.random_range(0.8..1.2),
                ]
            } else {
                random_colour(rng)
            };
            let a = rng.random_range(0.5..1.0f32);
            match rng.random_range(0..if notes { 5u8 } else { 4 }) {
                0 | 1 => {
                    let asp = rng.random_range(0.3..3.0f32);
                    self.rect(x, y, x + s * asp, y + s, c, a);
                }
                2 => self.ellipse(x, y, s * 0.5, s * rng.random_range(0.3..0.6), c, a),
                3 => {
                    let ang = rng.random_range(0.0..std::f32::consts::TAU);
                    let t = (s * 0.08).max(1.0);
                    self.line([x, y], [x + s * ang.cos(), y + s * ang.sin()], t, c);
                }
                _ => {
                    // a framed note with text
                    let w = s * rng.random_range(0.8..1.6f32);
                    self.rect(x, y, x + w, y + s, [0.95, 0.93, 0.85], 1.0);
                    self.text(rng, [x + 2.0, y + 2.0, x + w - 2.0, y + s - 2.0], 3.0, c);
                }
            }
        }
    }

    /// A poster: background colour, blocks, a circle, a heading and text.
    pub fn poster(&mut self, rng: &mut Pcg64Mcg, r: [f32; 4]) {
        let (w, h) = (r[2] - r[0], r[3] - r[1]);
        self.rect(
            r[0] - 3.0,
            r[1] - 3.0,
            r[2] + 3.0,
            r[3] + 3.0,
            [0.1, 0.1, 0.1],
            1.0,
        );
        self.rect(r[0], r[1], r[2], r[3], random_colour(rng), 1.0);
        for _ in 0..rng.random_range(2..6) {
            let x = r[0] + rng.random_range(0.0..w * 0.8);
            let y = r[1] + rng.random_range(0.0..h * 0.8);
            let s = rng.random_range(0.1..0.5f32);
            let c = random_colour(rng);
            if rng.random_bool(0.5) {
                self.rect(x, y, (x + w * s).min(r[2]), (y + h * s).min(r[3]), c, 1.0);
            } else {
                let rr = w.min(h) * s * 0.5;
                self.ellipse(x + rr, y + rr, rr, rr, c, 1.0);
            }
        }
        let g = (h * 0.04).max(3.0);
        self.text(
            rng,
            [
                r[0] + w * 0.1,
                r[1] + h * 0.6,
                r[2] - w * 0.1,
                r[3] - h * 0.05,
            ],
            g,
            [0.05, 0.05, 0.05],
        );
    }

    /// Multiply brightness by 1 + `amp` at the top row down to 1 - `amp` at the bottom (light from
    /// above).
    pub fn shade_vertical(&mut self, amp: f32) {
        for y in 0..self.height {
            let m = 1.0 + amp * (1.0 - 2.0 * y as f32 / self.height.max(1) as f32);
            for p in &mut self.data[y * self.width..(y + 1) * self.width] {
                for ch in p.iter_mut() {
                    *ch *= m;
                }
            }
        }
    }

    /// A lozenge (a square turned 45 degrees) outline of half-diagonal `r`, 2 texels wide.
    pub fn lozenge(&mut self, cx: f32, cy: f32, r: f32, c: [f32; 3], alpha: f32) {
        let ya = (cy - r).max(0.0) as usize;
        let yb = ((cy + r).min(self.height as f32 - 1.0).max(0.0)) as usize;
        let xa = (cx - r).max(0.0) as usize;
        let xb = ((cx + r).min(self.width as f32 - 1.0).max(0.0)) as usize;
        for y in ya..=yb {
            for x in xa..=xb {
                let d = (x as f32 - cx).abs() + (y as f32 - cy).abs();
                if d <= r && d > r - 2.0 {
                    blend(&mut self.data[y * self.width + x], c, alpha);
                }
            }
        }
    }

    /// Finish: clamp to bytes, fully opaque.
    pub fn into_texture(self) -> Texture {
        let data = self
            .data
            .iter()
            .map(|p| {
                [
                    (p[0] * 255.0).clamp(0.0, 255.0) as u8,
                    (p[1] * 255.0).clamp(0.0, 255.0) as u8,
                    (p[2] * 255.0).clamp(0.0, 255.0) as u8,
                    255,
                ]
            })
            .collect();
        Texture::from_level(Level {
            width: self.width,
            height: self.height,
            data,
        })
    }
}

#[inline]
fn blend(p: &mut [f32; 3], c: [f32; 3], a: f32) {
    for i in 0..3 {
        p[i] += (c[i] - p[i]) * a;
    }
}

/// A saturated random colour.
pub fn random_colour(rng: &mut Pcg64Mcg) -> [f32; 3] {
    let h = rng.random_range(0.0..6.0f32);
    let s = rng.random_range(0.3..0.9f32);
    let v = rng.random_range(0.3..0.95f32);
    let f = h.fract();
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f)));
    match h as u8 {
        0 => [v, t, p],
        1 => [q, v, p],
        2 => [p, v, t],
        3 => [p, q, v],
        4 => [t, p, v],
        _ => [v, p, q],
    }
}

/// Paint a procedural texture of `style` at `width` x `height` texels.
pub fn procedural(style: Style, width: usize, height: usize, rng: &mut Pcg64Mcg) -> Texture {
    let big = width.max(height) as f32;
    let mut c;
    match style {
        Style::Wall(base) => {
            c = Canvas::new(width, height, base);
            c.fbm(rng, big / 4.0, 0.12);
            c.scatter(rng, (width * height) / 6000, 3.0, big / 14.0, true, true);
            c.scatter(rng, (width * height) / 12000, 3.0, big / 20.0, false, false);
            for _ in 0..rng.random_range(3..6) {
                let pw = rng.random_range(big * 0.06..big * 0.16);
                let ph = pw * rng.random_range(0.7..1.5);
                let x = rng.random_range(0.0..(width as f32 - pw).max(1.0));
                let y = rng.random_range(height as f32 * 0.1..(height as f32 * 0.7).max(1.0));
                c.poster(rng, [x, y, x + pw, y + ph]);
            }
        }
        Style::Floor(base) => {
            c = Canvas::new(width, height, base);
            c.fbm(rng, big / 3.0, 0.18);
            for _ in 0..3 {
                let x = rng.random_range(0.0..width as f32);
                let y = rng.random_range(0.0..height as f32);
                let s = rng.random_range(big * 0.1..big * 0.25);
                c.rect(x, y, x + s * 1.4, y + s, random_colour(rng), 0.6);
            }
            c.value_noise(rng, 3.0, 0.1, 1.0);
            c.scatter(rng, (width * height) / 5000, 2.0, big / 25.0, true, false);
            c.scatter(rng, (width * height) / 40000, 8.0, big / 25.0, false, true);
        }
        Style::Wood(base) => {
            c = Canvas::new(width, height, base);
            c.value_noise(rng, big / 16.0, 0.25, 8.0);
            c.value_noise(rng, big / 64.0, 0.15, 10.0);
            c.value_noise(rng, 3.0, 0.06, 6.0);
            c.scatter(
                rng,
                (width * height) / 4000 + 4,
                4.0,
                big / 8.0,
                false,
                true,
            );
        }
        Style::Fabric(base) => {
            c = Canvas::new(width, height, base);
            c.fbm(rng, big / 4.0, 0.25);
            c.scatter(rng, (width * height) / 600 + 6, 2.0, big / 6.0, true, false);
        }
        Style::Cloth(base) => {
            c = Canvas::new(width, height, base);
            c.fbm(rng, big / 3.0, 0.12);
            c.value_noise(rng, 1.5, 0.05, 1.0);
        }
        Style::Head(skin, hair) => {
            c = Canvas::new(width, height, skin);
            c.fbm(rng, big / 4.0, 0.08);
            let (w, h) = (width as f32, height as f32);
            // hair all round the top and at the back (u near 0 and 1)
            c.rect(0.0, 0.0, w, h * 0.32, hair, 1.0);
            c.rect(0.0, 0.0, w * 0.3, h * 0.8, hair, 1.0);
            c.rect(w * 0.7, 0.0, w, h * 0.8, hair, 1.0);
            c.value_noise(rng, 3.0, 0.15, 1.0);
            // face at u = 0.5
            let eye = [0.12, 0.1, 0.08];
            c.ellipse(
                w * 0.44,
                h * 0.45,
                w * 0.025,
                h * 0.03,
                [0.95, 0.95, 0.95],
                1.0,
            );
            c.ellipse(
                w * 0.56,
                h * 0.45,
                w * 0.025,
                h * 0.03,
                [0.95, 0.95, 0.95],
                1.0,
            );
            c.ellipse(w * 0.44, h * 0.45, w * 0.012, h * 0.022, eye, 1.0);
            c.ellipse(w * 0.56, h * 0.45, w * 0.012, h * 0.022, eye, 1.0);
            c.rect(w * 0.42, h * 0.39, w * 0.47, h * 0.405, hair, 1.0);
            c.rect(w * 0.53, h * 0.39, w * 0.58, h * 0.405, hair, 1.0);
            c.rect(
                w * 0.49,
                h * 0.5,
                w * 0.51,
                h * 0.6,
                [skin[0] * 0.8, skin[1] * 0.7, skin[2] * 0.7],
                1.0,
            );
            c.rect(
                w * 0.46,
                h * 0.7,
                w * 0.54,
                h * 0.73,
                [0.6, 0.25, 0.25],
                1.0,
            );
        }
        Style::Skin(skin) => {
            c = Canvas::new(width, height, skin);
            c.fbm(rng, big / 2.0, 0.1);
        }
        Style::Screen => {
            c = Canvas::new(width, height, [0.08, 0.08, 0.09]);
            let (w, h) = (width as f32, height as f32);
            // the face of the screen is the "front" cell (0..1/3, 0..1/2) of the cuboid atlas
            let (sw, sh) = (w / 3.0, h / 2.0);
            c.rect(
                sw * 0.05,
                sh * 0.07,
                sw * 0.95,
                sh * 0.93,
                [0.2, 0.35, 0.6],
                1.0,
            );
            for _ in 0..rng.random_range(2..5) {
                let x = rng.random_range(sw * 0.05..sw * 0.6);
                let y = rng.random_range(sh * 0.07..sh * 0.6);
                let ww = rng.random_range(sw * 0.2..sw * 0.45);
                let hh = rng.random_range(sh * 0.2..sh * 0.4);
                let (x1, y1) = ((x + ww).min(sw * 0.95), (y + hh).min(sh * 0.93));
                c.rect(x, y, x1, y1, [0.92, 0.92, 0.92], 1.0);
                c.rect(x, y, x1, y + 4.0, random_colour(rng), 1.0);
                c.text(
                    rng,
                    [x + 3.0, y + 6.0, x1 - 3.0, y1 - 2.0],
                    2.5,
                    [0.1, 0.1, 0.2],
                );
            }
            c.value_noise(rng, 4.0, 0.03, 1.0);
        }
        Style::Cardboard => {
            c = Canvas::new(width, height, [0.62, 0.46, 0.3]);
            c.fbm(rng, big / 4.0, 0.12);
            let (w, h) = (width as f32, height as f32);
            c.rect(0.0, h * 0.22, w, h * 0.27, [0.8, 0.75, 0.6], 0.9);
            c.rect(0.0, h * 0.72, w, h * 0.77, [0.8, 0.75, 0.6], 0.9);
            for cell in 0..6 {
                let (cx, cy) = ((cell % 3) as f32 * w / 3.0, (cell / 3) as f32 * h / 2.0);
                let lx = cx + rng.random_range(w * 0.03..w * 0.15);
                let ly = cy + rng.random_range(h * 0.05..h * 0.15);
                c.rect(
                    lx,
                    ly,
                    lx + w * 0.12,
                    ly + h * 0.12,
                    [0.95, 0.95, 0.92],
                    1.0,
                );
                c.text(
                    rng,
                    [lx + 2.0, ly + 2.0, lx + w * 0.12 - 2.0, ly + h * 0.12],
                    2.5,
                    [0.1, 0.1, 0.1],
                );
                c.line(
                    [cx + w * 0.2, cy + h * 0.3],
                    [cx + w * 0.3, cy + h * 0.4],
                    2.0,
                    [0.1, 0.1, 0.1],
                );
            }
        }
        Style::Plain(base) => {
            c = Canvas::new(width, height, base);
            c.fbm(rng, big / 4.0, 0.08);
            c.scatter(rng, 6, 2.0, big / 10.0, true, false);
        }
        Style::Poster => {
            c = Canvas::new(width, height, [0.9, 0.9, 0.88]);
            let (w, h) = (width as f32, height as f32);
            c.poster(rng, [w * 0.05, h * 0.05, w * 0.95, h * 0.95]);
        }
        Style::Books => {
            c = Canvas::new(width, height, [0.3, 0.3, 0.3]);
            let mut x = 0.0;
            while x < width as f32 {
                let bw = rng.random_range(width as f32 * 0.02..width as f32 * 0.06);
                let top = rng.random_range(0.0..height as f32 * 0.25);
                let col = random_colour(rng);
                c.rect(x, top, x + bw, height as f32, col, 1.0);
                c.rect(
                    x,
                    top + height as f32 * 0.15,
                    x + bw,
                    top + height as f32 * 0.2,
                    [0.9, 0.85, 0.5],
                    0.8,
                );
                x += bw + 1.0;
            }
            c.value_noise(rng, 4.0, 0.08, 1.0);
        }
        Style::Paint(base) => {
            c = Canvas::new(width, height, base);
            c.fbm(rng, big / 3.0, 0.025);
            c.shade_vertical(0.05);
        }
        Style::Carpet(base) => {
            c = Canvas::new(width, height, base);
            c.fbm(rng, big / 4.0, 0.04);
            c.value_noise(rng, 2.0, 0.02, 1.0);
        }
        Style::Rug(base, border) => {
            c = Canvas::new(width, height, base);
            let (w, h) = (width as f32, height as f32);
            let b = 0.08 * w.min(h);
            c.rect(0.0, 0.0, w, h, border, 1.0);
            c.rect(b, b, w - b, h - b, base, 1.0);
            // faint lozenges in the field
            let cell = 0.12 * w.min(h);
            let mut yy = b + cell;
            while yy < h - b - cell * 0.5 {
                let mut xx = b + cell;
                while xx < w - b - cell * 0.5 {
                    c.lozenge(xx, yy, cell * 0.35, border, 0.25);
                    xx += cell;
                }
                yy += cell;
            }
            c.fbm(rng, big / 4.0, 0.05);
            c.value_noise(rng, 2.0, 0.03, 1.0);
        }
        Style::Painting => {
            let (w, h) = (width as f32, height as f32);
            let sky = [
                rng.random_range(0.45..0.65f32),
                rng.random_range(0.6..0.75),
                rng.random_range(0.75..0.85),
            ];
            c = Canvas::new(width, height, sky);
            // the frame and a light mat
            let f = 0.06 * w.min(h);
            let m = 0.1 * w.min(h);
            c.rect(0.0, 0.0, w, h, [0.25, 0.18, 0.12], 1.0);
            c.rect(f, f, w - f, h - f, [0.88, 0.86, 0.8], 1.0);
            c.rect(m + f, m + f, w - m - f, h - m - f, sky, 1.0);
            let (x0, y0, x1, y1) = (m + f, m + f, w - m - f, h - m - f);
            let sun = [0.95, 0.85, 0.55];
            let r = 0.07 * (x1 - x0);
            c.ellipse(
                x0 + rng.random_range(0.2..0.8f32) * (x1 - x0),
                y0 + 0.25 * (y1 - y0),
                r,
                r,
                sun,
                0.8,
            );
            for k in 0..3 {
                let g = 0.55 - 0.1 * k as f32;
                let col = [g * 0.6, g, g * 0.5];
                let cy = y0 + (0.55 + 0.12 * k as f32) * (y1 - y0);
                let cx = x0 + rng.random_range(0.0..1.0f32) * (x1 - x0);
                let rx = rng.random_range(0.5..0.9f32) * (x1 - x0);
                c.ellipse(cx, cy + 0.3 * (y1 - y0), rx, 0.35 * (y1 - y0), col, 1.0);
            }
            // keep the hills inside the mat
            c.rect(0.0, y1, w, h, [0.88, 0.86, 0.8], 1.0);
            c.rect(0.0, h - f, w, h, [0.25, 0.18, 0.12], 1.0);
            c.rect(0.0, 0.0, x0, h, [0.88, 0.86, 0.8], 1.0);
            c.rect(x1, 0.0, w, h, [0.88, 0.86, 0.8], 1.0);
            c.rect(0.0, 0.0, f, h, [0.25, 0.18, 0.12], 1.0);
            c.rect(w - f, 0.0, w, h, [0.25, 0.18, 0.12], 1.0);
            c.fbm(rng, big / 4.0, 0.04);
        }
        Style::Upholstery(base) => {
            c = Canvas::new(width, height, base);
            c.fbm(rng, big / 3.0, 0.07);
            c.value_noise(rng, 2.0, 0.025, 1.0);
        }
        Style::Panel(base) => {
            c = Canvas::new(width, height, base);
            let (w, h) = (width as f32, height as f32);
            let shadow = [base[0] * 0.8, base[1] * 0.8, base[2] * 0.8];
            for (ya, yb) in [(0.08, 0.45), (0.53, 0.92)] {
                let r = [w * 0.15, h * ya, w * 0.85, h * yb];
                c.rect(r[0], r[1], r[2], r[3], shadow, 0.35);
                c.rect(r[0] + 3.0, r[1] + 3.0, r[2] - 3.0, r[3] - 3.0, base, 1.0);
            }
            c.fbm(rng, big / 3.0, 0.02);
        }
        Style::Grain(base) => {
            c = Canvas::new(width, height, base);
            c.value_noise(rng, big / 16.0, 0.2, 8.0);
            c.value_noise(rng, big / 64.0, 0.1, 10.0);
            c.value_noise(rng, 3.0, 0.04, 6.0);
        }
        Style::Plaid(a, b) => {
            c = Canvas::new(width, height, a);
            let period = (big / 20.0).max(8.0);
            let dark = [a[0] * 0.2, a[1] * 0.2, a[2] * 0.2];
            let light = [0.92, 0.92, 0.9];
            for y in 0..height {
                for x in 0..width {
                    let (fx, fy) = ((x as f32 / period).fract(), (y as f32 / period).fract());
                    let p = &mut c.data[y * width + x];
                    if fx < 0.45 {
                        blend(p, b, 0.6);
                    }
                    if fy < 0.45 {
                        blend(p, b, 0.6);
                    }
                    if (0.62..0.7).contains(&fx) || (0.62..0.7).contains(&fy) {
                        blend(p, light, 0.7);
                    }
                    if (0.84..0.9).contains(&fx) || (0.84..0.9).contains(&fy) {
                        blend(p, dark, 0.8);
                    }
                }
            }
            c.fbm(rng, big / 3.0, 0.12);
            c.value_noise(rng, 1.5, 0.04, 1.0);
        }
        Style::Floral(base) => {
            c = Canvas::new(width, height, base);
            let n = width * height / 700;
            for _ in 0..n {
                let x = rng.random_range(0.0..width as f32);
                let y = rng.random_range(0.0..height as f32);
                let r = rng.random_range(big * 0.012..big * 0.035);
                let col = random_colour(rng);
                let ang = rng.random_range(0.0..std::f32::consts::TAU);
                if rng.random_bool(0.3) {
                    // a leaf
                    let leaf = [0.1, rng.random_range(0.3..0.55), 0.12];
                    let d = [ang.cos(), ang.sin()];
                    c.line(
                        [x, y],
                        [x + 2.0 * r * d[0], y + 2.0 * r * d[1]],
                        r * 0.6,
                        leaf,
                    );
                    continue;
                }
                for k in 0..5 {
                    let a = ang + k as f32 * std::f32::consts::TAU / 5.0;
                    c.ellipse(x + r * a.cos(), y + r * a.sin(), r * 0.6, r * 0.6, col, 1.0);
                }
                c.ellipse(x, y, r * 0.45, r * 0.45, [0.95, 0.85, 0.2], 1.0);
            }
            c.fbm(rng, big / 3.0, 0.1);
        }
        Style::Denim(base) => {
            c = Canvas::new(width, height, base);
            let (w, h) = (width as f32, height as f32);
            for y in 0..height {
                for x in 0..width {
                    if (x + y) % 4 < 2 {
                        let p = &mut c.data[y * width + x];
                        for ch in p.iter_mut() {
                            *ch *= 0.85;
                        }
                    }
                }
            }
            c.fbm(rng, big / 3.0, 0.2);
            // faded front (u = 0.5 faces forward) and knees
            c.ellipse(w * 0.5, h * 0.55, w * 0.12, h * 0.2, [0.6, 0.68, 0.8], 0.35);
            let stitch = [0.8, 0.6, 0.25];
            for u in [0.25, 0.75] {
                c.rect(w * u - 2.0, 0.0, w * u + 2.0, h, [0.1, 0.12, 0.2], 0.8);
                c.rect(w * u + 3.0, 0.0, w * u + 4.0, h, stitch, 0.9);
                c.rect(w * u - 4.0, 0.0, w * u - 3.0, h, stitch, 0.9);
            }
            // pocket outlines near the top, back and front, and a hem
            for u in [0.05, 0.4, 0.6, 0.95] {
                let (x0, x1) = (w * u - w * 0.06, w * u + w * 0.06);
                c.rect(x0, h * 0.02, x1, h * 0.02 + 2.0, stitch, 0.9);
                c.rect(x0, h * 0.02, x0 + 2.0, h * 0.18, stitch, 0.9);
                c.rect(x1 - 2.0, h * 0.02, x1, h * 0.18, stitch, 0.9);
                c.rect(x0, h * 0.18, x1, h * 0.18 + 2.0, stitch, 0.9);
            }
            c.rect(0.0, h - 6.0, w, h - 4.0, stitch, 0.9);
            c.value_noise(rng, 1.5, 0.05, 1.0);
        }
        Style::Camo => {
            c = Canvas::new(width, height, [0.55, 0.52, 0.38]);
            let palette = [[0.3, 0.33, 0.18], [0.35, 0.25, 0.15], [0.12, 0.12, 0.1]];
            for col in palette {
                for _ in 0..(width * height / 900) {
                    let x = rng.random_range(0.0..width as f32);
                    let y = rng.random_range(0.0..height as f32);
                    let r = rng.random_range(big * 0.02..big * 0.06);
                    for _ in 0..3 {
                        let dx = rng.random_range(-r..r);
                        let dy = rng.random_range(-r..r);
                        let rx = r * rng.random_range(0.5..1.0);
                        c.ellipse(
                            x + dx,
                            y + dy,
                            rx,
                            rx * rng.random_range(0.5..1.0),
                            col,
                            1.0,
                        );
                    }
                }
            }
            c.fbm(rng, big / 3.0, 0.1);
            c.value_noise(rng, 1.5, 0.04, 1.0);
        }
        Style::Leaves => {
            c = Canvas::new(width, height, [0.12, 0.3, 0.1]);
            for _ in 0..(width * height / 40) {
                let x = rng.random_range(0.0..width as f32);
                let y = rng.random_range(0.0..height as f32);
                let g = rng.random_range(0.2..0.6f32);
                c.ellipse(
                    x,
                    y,
                    rng.random_range(2.0..7.0),
                    rng.random_range(1.0..3.0),
                    [g * 0.5, g, g * 0.3],
                    1.0,
                );
            }
        }
    }
    c.into_texture()
}

/// Image files (png, jpg, jpeg) under `dir`, recursively, sorted by path (deterministic).
pub fn image_files(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d)? {
            let p = entry?.path();
            if p.is_dir() {
                stack.push(p);
            } else if let Some(ext) = p.extension().and_then(|e| e.to_str())
                && ["png", "jpg", "jpeg"].contains(&ext.to_ascii_lowercase().as_str())
            {
                out.push(p);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// A photo as an opaque texture, halved until it is at most 1024 texels wide.
pub fn photo_texture(img: &Rgb8) -> Texture {
    let base = Level {
        width: img.width,
        height: img.height,
        data: img.data.iter().map(|p| [p[0], p[1], p[2], 255]).collect(),
    };
    let mut t = Texture::from_level(base);
    while t.levels.len() > 1 && t.levels[0].width > 1024 {
        t.levels.remove(0);
    }
    t
}

/// Cut a person out of `rgb` with `mask` (non-zero = person): the largest 4-connected mask
/// component that does not touch the left, right or top border (a whole person), cropped to its
/// box, transparent elsewhere. `None` when the mask holds no such component.
pub fn person_cutout(rgb: &Rgb8, mask: &stillpoint_image::Gray8) -> Option<Texture> {
    if rgb.width != mask.width || rgb.height != mask.height || rgb.is_empty() {
        return None;
    }
    let (w, h) = (mask.width, mask.height);
    let mut label = vec![0u32; w * h];
    let mut best: Option<(usize, [usize; 4], u32)> = None;
    let mut next = 0u32;
    let mut stack = Vec::new();
    for start in 0..w * h {
        if mask.data[start] < 128 || label[start] != 0 {
            continue;
        }
        next += 1;
        label[start] = next;
        stack.push(start);
        let (mut n, mut bb) = (0usize, [w, h, 0usize, 0usize]);
        while let Some(i) = stack.pop() {
            let (x, y) = (i % w, i / w);
            n += 1;
            bb = [bb[0].min(x), bb[1].min(y), bb[2].max(x), bb[3].max(y)];
            let mut push = |j: usize| {
                if mask.data[j] >= 128 && label[j] == 0 {
                    label[j] = next;
                    stack.push(j);
                }
            };
            if x > 0 {
                push(i - 1);
            }
            if x + 1 < w {
                push(i + 1);
            }
            if y > 0 {
                push(i - w);
            }
            if y + 1 < h {
                push(i + w);
            }
        }
        let whole = bb[0] > 0 && bb[1] > 0 && bb[2] + 1 < w;
        if whole && best.is_none_or(|b| n > b.0) {
            best = Some((n, bb, next));
        }
    }
    let (_, bb, id) = best?;
    let (cw, ch) = (bb[2] - bb[0] + 1, bb[3] - bb[1] + 1);
    let mut data = Vec::with_capacity(cw * ch);
    for y in bb[1]..=bb[3] {
        for x in bb[0]..=bb[2] {
            let p = rgb.get(x, y);
            let a = if label[y * w + x] == id { 255 } else { 0 };
            data.push([p[0], p[1], p[2], a]);
        }
    }
    Some(Texture::from_level(Level {
        width: cw,
        height: ch,
        data,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn procedural_textures_are_deterministic_and_not_flat() {
        let t1 = procedural(
            Style::Wall([0.8, 0.8, 0.75]),
            128,
            64,
            &mut Pcg64Mcg::seed_from_u64(3),
        );
        let t2 = procedural(
            Style::Wall([0.8, 0.8, 0.75]),
            128,
            64,
            &mut Pcg64Mcg::seed_from_u64(3),
        );
        assert_eq!(t1.levels[0].data, t2.levels[0].data);
        let lum: Vec<f32> = t1.levels[0].data.iter().map(|p| p[1] as f32).collect();
        let mean = lum.iter().sum::<f32>() / lum.len() as f32;
        let var = lum.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / lum.len() as f32;
        assert!(var.sqrt() > 5.0, "texture too flat: std {}", var.sqrt());
        assert_eq!(t1.levels.last().unwrap().width, 1);
    }

    #[test]
    fn cutout_keeps_whole_component_and_makes_rest_transparent() {
        let rgb = Rgb8::new(10, 10, [200, 100, 50]);
        let mut mask = stillpoint_image::Gray8::new(10, 10, 0);
        for y in 2..9 {
            for x in 3..6 {
                mask.set(x, y, 255);
            }
        }
        mask.set(9, 5, 255); // touches the right border: not a whole person
        let t = person_cutout(&rgb, &mask).unwrap();
        assert_eq!(t.size(), (3, 7));
        assert!(t.levels[0].data.iter().all(|p| p[3] == 255));
        assert!(person_cutout(&rgb, &stillpoint_image::Gray8::new(10, 10, 0)).is_none());
    }
}
