//! Regions of an image that hold movers: boxes with the depth band found for each, drawn into a
//! mask on a frame's depth.

use stillpoint_dynamic::{DepthParams, depth::ObjectDepth};
use stillpoint_image::{DepthMetres, Gray8};

/// A mover's box (`[x1, y1, x2, y2]`) and the depth band the culling found for it, if any.
pub type ObjectRegion = ([f32; 4], Option<ObjectDepth>);

/// Boxes of objects and their depth bands, to draw on a depth image ([`Regions::mask`]).
#[derive(Clone, Debug, Default)]
pub struct Regions {
    objects: Vec<ObjectRegion>,
    params: DepthParams,
    up_to_far: bool,
    /// As ORB's budget mask: the share of the budget below which the mask drawn without depth
    /// gives way ([`Regions::min_yield`]); 0 = never.
    min_yield: f32,
    /// Drawn without depth: only discs of this radius (pixels) around these points, inside the
    /// boxes ([`Regions::with_discs`]); `None`: the whole boxes.
    discs: Option<(Vec<[f32; 2]>, f32)>,
}

impl Regions {
    /// `objects` drawn with `params` (a band missing is estimated from the box alone);
    /// `up_to_far`: in each box, anything in front of the band's far end too (a close person's
    /// head and hands lie outside their torso's band).
    pub fn new(objects: Vec<ObjectRegion>, params: &DepthParams, up_to_far: bool) -> Self {
        Self {
            objects,
            params: params.clone(),
            up_to_far,
            min_yield: 0.0,
            discs: None,
        }
    }

    /// The same regions, drawn without depth as discs of `radius` pixels around `points`
    /// (where the movers' pixels are expected) inside the boxes, instead of the whole boxes:
    /// a walker's box is mostly the room behind him.
    pub fn with_discs(mut self, points: Vec<[f32; 2]>, radius: f32) -> Self {
        self.discs = Some((points, radius));
        self
    }

    /// The same regions, whose mask as ORB's budget mask, drawn without depth (whole boxes),
    /// gives way when it leaves fewer than `share` of the budget ([`Regions::min_yield`]).
    pub fn with_min_yield(mut self, share: f32) -> Self {
        self.min_yield = share;
        self
    }

    /// As ORB's budget mask drawn without depth: when the extraction it masks finds fewer than
    /// this share of the budget, the budget left goes to the masked pixels (0: never).
    pub fn min_yield(&self) -> f32 {
        self.min_yield
    }

    /// No region.
    pub fn is_empty(&self) -> bool {
        self.objects.is_empty()
    }

    /// The boxes, `[x1, y1, x2, y2]`.
    pub fn boxes(&self) -> impl Iterator<Item = [f32; 4]> + '_ {
        self.objects.iter().map(|(b, _)| *b)
    }

    /// The regions' pixels (255) in an image `width` x `height`: with depth, those of each box
    /// within its object's depth band; without, the whole boxes. `None` when there is no region.
    pub fn mask(&self, depth: Option<&DepthMetres>, width: usize, height: usize) -> Option<Gray8> {
        (!self.objects.is_empty()).then(|| {
            let mut mask = mover_mask(
                &self.objects,
                depth,
                &self.params,
                width,
                height,
                self.up_to_far,
            );
            if let (None, Some((points, radius))) = (depth, &self.discs) {
                keep_discs(&mut mask, points, *radius);
            }
            mask
        })
    }
}

/// Keep of `mask` only the pixels within `radius` of some point.
fn keep_discs(mask: &mut Gray8, points: &[[f32; 2]], radius: f32) {
    let (w, h) = (mask.width, mask.height);
    let mut near = Gray8::new(w, h, 0);
    let r = radius.max(0.0);
    for &[px, py] in points
        .iter()
        .filter(|p| p[0].is_finite() && p[1].is_finite())
    {
        let clamp = |v: f32, n: usize| (v.max(0.0) as usize).min(n);
        let (x1, x2) = (clamp((px - r).floor(), w), clamp((px + r).ceil() + 1.0, w));
        let (y1, y2) = (clamp((py - r).floor(), h), clamp((py + r).ceil() + 1.0, h));
        for y in y1..y2 {
            let dy = y as f32 - py;
            for x in x1..x2 {
                let dx = x as f32 - px;
                if dx * dx + dy * dy <= r * r {
                    near.set(x, y, 255);
                }
            }
        }
    }
    for (m, n) in mask.data.iter_mut().zip(&near.data) {
        *m &= *n;
    }
}

/// The pixels of movers (255) inside their boxes: with depth, those within each object's depth
/// band (the culling's, else estimated from the box alone by `dynamic::depth::object_depth`)
/// or, `up_to_far`, anything in front of the band's far end too; without depth, or with too
/// few depth samples, the whole box.
fn mover_mask(
    rects: &[ObjectRegion],
    depth: Option<&DepthMetres>,
    d: &DepthParams,
    width: usize,
    height: usize,
    up_to_far: bool,
) -> Gray8 {
    let mut mask = Gray8::new(width, height, 0);
    for (r, known) in rects {
        let [x1, y1, x2, y2] = pixel_span(r, width, height);
        let bbox = stillpoint_geometry::BBox::new(r[0], r[1], r[2], r[3]);
        if x1 >= x2 {
            continue;
        }
        let object = depth.and_then(|z| {
            known.or_else(|| {
                stillpoint_dynamic::depth::object_depth(&bbox, &[], z, None, f32::INFINITY, d)
            })
        });
        // Row by row on slices: this runs on every frame over boxes that can hold half the
        // image, and pixel by pixel it was 5 % of a live run's tracking thread.
        for y in y1..y2 {
            let row = &mut mask.data[y * width..][x1..x2];
            let (Some(o), Some(z)) = (object, depth) else {
                row.fill(255);
                continue;
            };
            // Past the depth image's edge nothing is a mover (no depth to say so).
            if y >= z.height {
                continue;
            }
            let z_row = &z.row(y)[x1.min(z.width)..];
            let n = row.len().min(z_row.len());
            mark_movers_in_row(&mut row[..n], &z_row[..n], x1, y, &o, up_to_far);
        }
    }
    mask
}

/// The pixels a box `[x1, y1, x2, y2]` covers in an image `width` x `height`, as column and
/// row ranges `[x1, y1, x2, y2]` (ends excluded, clipped to the image; empty when inverted).
fn pixel_span(r: &[f32; 4], width: usize, height: usize) -> [usize; 4] {
    let clamp = |v: f32, hi: usize| (v.max(0.0) as usize).min(hi);
    [
        clamp(r[0], width),
        clamp(r[1], height),
        clamp(r[2], width),
        clamp(r[3], height),
    ]
}

stillpoint_features::simd_fn! {
/// Sets `row[i]` (column `x0 + i` of row `y`) to 255 where its depth `z[i]` is the mover's:
/// in `o`'s band (or, `up_to_far`, in front of its far end) and not on the plane it stands on.
/// The same tests as [`ObjectDepth::holds`] and [`ObjectDepth::on_support`], in their order of
/// operations, without branches, so the loop runs eight pixels at a time where the CPU has AVX2.
fn mark_movers_in_row(
    row: &mut [u8],
    z: &[f32],
    x0: usize,
    y: usize,
    o: &ObjectDepth,
    up_to_far: bool,
) {
    let (near, far, yf) = (o.near, o.far, y as f32);
    let in_band = |v: f32| (v >= near) & (v <= far) | (up_to_far & (v > 0.0) & (v <= far));
    let pixels = row.iter_mut().zip(z);
    match o.support.filter(|s| yf >= s.from_row) {
        None => {
            for (m, &v) in pixels {
                *m |= 0u8.wrapping_sub(in_band(v) as u8);
            }
        }
        Some(s) => {
            for (i, (m, &v)) in pixels.enumerate() {
                let distance = (v * (s.a * (x0 + i) as f32 + s.b * yf + s.c) + s.d).abs();
                let on_support =
                    (v > 0.0) & (distance <= s.tolerance_m.max(s.tolerance_relative * v));
                *m |= 0u8.wrapping_sub((in_band(v) & !on_support) as u8);
            }
        }
    }
}
}

#[cfg(test)]
mod tests {
    use super::*;
    use stillpoint_dynamic::depth::{ObjectDepth, SupportPlane};

    /// The rule the mask draws, pixel by pixel: every pixel of a box without depth (or without
    /// a band); with both, one whose depth the band holds (or, `up_to_far`, anything in front
    /// of its far end) and that is not on the plane the object stands on.
    fn mask_pixel_by_pixel(
        rects: &[([f32; 4], Option<ObjectDepth>)],
        depth: Option<&DepthMetres>,
        width: usize,
        height: usize,
        up_to_far: bool,
    ) -> Gray8 {
        let mut mask = Gray8::new(width, height, 0);
        for (r, object) in rects {
            let [x1, y1, x2, y2] = pixel_span(r, width, height);
            for y in y1..y2 {
                for x in x1..x2 {
                    let on_mover = match (object, depth) {
                        (Some(o), Some(z)) => {
                            z.get_checked(x as isize, y as isize).is_some_and(|v| {
                                (o.holds(v) || (up_to_far && v > 0.0 && v <= o.far))
                                    && !o.on_support(x as f32, y as f32, v)
                            })
                        }
                        _ => true,
                    };
                    if on_mover {
                        mask.set(x, y, 255);
                    }
                }
            }
        }
        mask
    }

    #[test]
    fn the_mask_drawn_by_rows_is_the_pixel_by_pixel_rule() {
        // Depth smaller than the image (its last columns and rows have none), a floor the
        // object stands on in its lower rows, a band, holes.
        let (w, h) = (90, 70);
        let mut depth = DepthMetres::new(80, 60, 0.0);
        for y in 0..60 {
            for x in 0..80 {
                let z = match (x * 7 + y * 13) % 11 {
                    0 => 0.0,
                    k => 0.8 + 0.35 * k as f32,
                };
                depth.set(x, y, z);
            }
        }
        let support = SupportPlane {
            a: 0.0,
            b: 0.01,
            c: -0.2,
            d: -0.1,
            from_row: 40.0,
            tolerance_m: 0.4,
            tolerance_relative: 0.05,
        };
        let band = |support| ObjectDepth {
            metres: 2.0,
            near: 1.5,
            far: 2.6,
            samples: 100,
            central_share: 0.8,
            outliers_with_depth: 0,
            outliers_in_band: 0,
            support,
        };
        let rects = vec![
            ([10.0, 5.0, 50.0, 65.0], Some(band(Some(support)))),
            ([-5.0, 30.0, 95.0, 80.0], Some(band(None))),
            ([60.0, 10.0, 40.0, 20.0], Some(band(None))),
            ([70.0, 50.0, 88.5, 69.5], Some(band(Some(support)))),
        ];
        let params = stillpoint_dynamic::DepthParams::default();
        for up_to_far in [false, true] {
            for z in [Some(&depth), None] {
                let drawn = Regions::new(rects.clone(), &params, up_to_far)
                    .mask(z, w, h)
                    .expect("regions");
                let expected = mask_pixel_by_pixel(&rects, z, w, h, up_to_far);
                assert_eq!(
                    drawn,
                    expected,
                    "up_to_far {up_to_far}, depth {}",
                    z.is_some()
                );
            }
        }
        // The rule draws some pixels of the boxes and leaves others.
        let some = mask_pixel_by_pixel(&rects, Some(&depth), w, h, false);
        let set = some.data.iter().filter(|&&m| m == 255).count();
        assert!(set > 100 && set < 3000, "{set} pixels set");
    }

    #[test]
    fn the_orb_mask_covers_a_mover_but_not_the_background_in_its_box() {
        // A person 1.5 m away fills the middle of a 100 x 100 box; the wall 4 m behind shows
        // around them inside the box.
        let mut depth = DepthMetres::new(200, 200, 4.0);
        for y in 50..150 {
            for x in 75..125 {
                depth.set(x, y, 1.5);
            }
        }
        let params = stillpoint_dynamic::DepthParams::default();
        let rect = ([50.0, 50.0, 150.0, 150.0], None);
        let mask = Regions::new(vec![rect], &params, false)
            .mask(Some(&depth), 200, 200)
            .expect("a region");
        assert_eq!(mask.get(100, 100), 255, "the person");
        assert_eq!(mask.get(60, 100), 0, "the wall beside them, inside the box");
        assert_eq!(mask.get(10, 10), 0, "outside the box");
        // Without depth the whole box.
        let whole = Regions::new(vec![rect], &params, false)
            .mask(None, 200, 200)
            .expect("a region");
        assert_eq!((whole.get(60, 100), whole.get(10, 10)), (255, 0));
        // Without depth, with discs: only their pixels inside the box.
        let discs = Regions::new(vec![rect], &params, false)
            .with_discs(vec![[100.0, 100.0], [10.0, 10.0]], 8.0)
            .mask(None, 200, 200)
            .expect("a region");
        assert_eq!(
            (
                discs.get(100, 100),
                discs.get(106, 100),
                discs.get(60, 100),
                discs.get(10, 10)
            ),
            (255, 255, 0, 0)
        );
        // A thin person: the box's centre is mostly wall, which the box alone takes for the
        // mover; the band the culling found (with the person's moving tracks) is kept instead.
        let mut thin = DepthMetres::new(200, 200, 4.0);
        for y in 50..150 {
            for x in 95..105 {
                thin.set(x, y, 1.5);
            }
        }
        let blind = Regions::new(vec![rect], &params, false)
            .mask(Some(&thin), 200, 200)
            .expect("a region");
        assert_eq!((blind.get(100, 100), blind.get(60, 100)), (0, 255));
        let band = stillpoint_dynamic::depth::object_depth(
            &stillpoint_geometry::BBox::new(95.0, 50.0, 105.0, 150.0),
            &[],
            &thin,
            None,
            f32::INFINITY,
            &params,
        );
        let known = Regions::new(vec![(rect.0, band)], &params, false)
            .mask(Some(&thin), 200, 200)
            .expect("a region");
        assert_eq!((known.get(100, 100), known.get(60, 100)), (255, 0));
    }
}
