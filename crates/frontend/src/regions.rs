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
        let clamp = |v: f32, hi: usize| (v.max(0.0) as usize).min(hi);
        let (x1, y1) = (clamp(r[0], width), clamp(r[1], height));
        let (x2, y2) = (clamp(r[2], width), clamp(r[3], height));
        let bbox = stillpoint_geometry::BBox::new(r[0], r[1], r[2], r[3]);
        let object = depth.and_then(|z| {
            known.or_else(|| {
                stillpoint_dynamic::depth::object_depth(&bbox, &[], z, None, f32::INFINITY, d)
            })
        });
        for y in y1..y2 {
            for x in x1..x2 {
                let on_mover = match (object, depth) {
                    (Some(o), Some(z)) => z.get_checked(x as isize, y as isize).is_some_and(|v| {
                        (o.holds(v) || (up_to_far && v > 0.0 && v <= o.far))
                            && !o.on_support(x as f32, y as f32, v)
                    }),
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

#[cfg(test)]
mod tests {
    use super::*;

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
