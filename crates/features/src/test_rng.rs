//! The one pseudo-random generator the unit tests build their synthetic data from (the
//! Numerical Recipes LCG), so every test draws the same way.

/// Linear congruential generator; the state is the last value drawn.
pub(crate) struct Lcg(pub u32);

impl Lcg {
    pub(crate) fn next_u32(&mut self) -> u32 {
        self.0 = self.0.wrapping_mul(1664525).wrapping_add(1013904223);
        self.0
    }

    /// The top byte of the next draw.
    pub(crate) fn byte(&mut self) -> u8 {
        (self.next_u32() >> 24) as u8
    }

    /// The next draw in [0, 1), from its top 24 bits.
    pub(crate) fn unit(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 / (1u32 << 24) as f32
    }

    /// A `w` x `h` image of independent random bytes.
    pub(crate) fn noise_image(&mut self, w: usize, h: usize) -> stillpoint_image::Gray8 {
        let mut img = stillpoint_image::Gray8::new(w, h, 0);
        for v in img.data.iter_mut() {
            *v = self.byte();
        }
        img
    }
}
