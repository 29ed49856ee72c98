//! Axis-aligned boxes in pixel coordinates (detections, ground-truth object boxes).

use serde::{Deserialize, Serialize};

/// A box in pixels: x1 <= x2, y1 <= y2, x right and y down, corners inclusive-exclusive in the
/// usual continuous sense (a point is inside when x1 < x < x2 and y1 < y < y2, strictly, as the
/// paper's authors test it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BBox {
    /// Left edge.
    pub x1: f32,
    /// Top edge.
    pub y1: f32,
    /// Right edge.
    pub x2: f32,
    /// Bottom edge.
    pub y2: f32,
}

impl BBox {
    /// The box from its left, top, right and bottom edges.
    pub fn new(x1: f32, y1: f32, x2: f32, y2: f32) -> Self {
        Self { x1, y1, x2, y2 }
    }
    /// Width, 0 for an inverted box.
    pub fn width(&self) -> f32 {
        (self.x2 - self.x1).max(0.0)
    }
    /// Height, 0 for an inverted box.
    pub fn height(&self) -> f32 {
        (self.y2 - self.y1).max(0.0)
    }
    /// Area in square pixels.
    pub fn area(&self) -> f32 {
        self.width() * self.height()
    }
    /// Strictly inside (the authors' test; a point on the edge is outside).
    pub fn contains_strict(&self, x: f32, y: f32) -> bool {
        x > self.x1 && x < self.x2 && y > self.y1 && y < self.y2
    }
    /// Intersection over union; 0 for empty boxes.
    pub fn iou(&self, o: &BBox) -> f32 {
        let w = (self.x2.min(o.x2) - self.x1.max(o.x1)).max(0.0);
        let h = (self.y2.min(o.y2) - self.y1.max(o.y1)).max(0.0);
        let inter = w * h;
        let union = self.area() + o.area() - inter;
        if union > 0.0 { inter / union } else { 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn iou_and_contains() {
        let a = BBox::new(0.0, 0.0, 10.0, 10.0);
        let b = BBox::new(5.0, 0.0, 15.0, 10.0);
        assert!((a.iou(&b) - 1.0 / 3.0).abs() < 1e-6);
        assert!(a.contains_strict(5.0, 5.0));
        assert!(!a.contains_strict(10.0, 5.0));
        assert_eq!(BBox::default().iou(&BBox::default()), 0.0);
    }
}
