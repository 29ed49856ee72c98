//! A sanity check of a depth map's scale: a wrong depth factor (1000 where the dataset uses
//! 5000, or the reverse) gives a trajectory scaled by the ratio with nothing inside the SLAM
//! system to contradict it, so the only place to catch it is the depth values themselves.

use stillpoint_image::DepthMetres;

/// Median depth of a plausible RGB-D frame, metres. Kinect, Xtion and RealSense return depth
/// from about 0.3-0.5 m and little past 5-8 m, so most of a frame cannot be nearer than 0.4 m or
/// farther than 6 m (real TUM fr1 desk: 1.5 m; ICL-NUIM living room: 1.4-3.0 m). The commonest
/// mistake, millimetres (1000) read as TUM's 5000 or the reverse, moves the median 5x: out of
/// this range for most rooms.
pub const RGBD_MEDIAN_RANGE_M: [f32; 2] = [0.4, 6.0];

/// Factors that real datasets use (TUM, Bonn and ICL-NUIM 5000; most others 1000 = mm).
const COMMON_FACTORS: [f64; 2] = [5000.0, 1000.0];

/// A typical indoor median depth (metres), to choose between common factors.
const TYPICAL_DEPTH_M: f64 = 2.0;

/// A warning when the median of the valid (finite, positive) depths of `depth`, read with
/// `depth_factor`, lies outside [`RGBD_MEDIAN_RANGE_M`]; it names a common factor that would put
/// the median in range. `None` when the scale looks right or fewer than 1 % of the pixels have
/// depth (a blank frame says nothing about the factor).
///
/// ```
/// use stillpoint_datasets::depth_scale_warning;
/// use stillpoint_image::DepthMetres;
/// // TUM stores 5000 per metre: a wall at 2 m is 10000, which read with 1000 is 10 m.
/// let wall = DepthMetres::new(64, 48, 10.0);
/// let w = depth_scale_warning(&wall, 1000.0).unwrap();
/// assert!(w.contains("5000"), "{w}");
/// assert!(depth_scale_warning(&DepthMetres::new(64, 48, 2.0), 5000.0).is_none());
/// ```
pub fn depth_scale_warning(depth: &DepthMetres, depth_factor: f64) -> Option<String> {
    // Every 4th pixel of every 4th row: plenty for a median, and cheap on every frame size.
    let mut valid: Vec<f32> = (0..depth.height)
        .step_by(4)
        .flat_map(|y| depth.row(y).iter().step_by(4).copied())
        .filter(|z| z.is_finite() && *z > 0.0)
        .collect();
    let sampled = depth.height.div_ceil(4) * depth.width.div_ceil(4);
    if valid.is_empty() || valid.len() * 100 < sampled {
        return None;
    }
    let mid = valid.len() / 2;
    let median = *valid.select_nth_unstable_by(mid, f32::total_cmp).1;
    let [lo, hi] = RGBD_MEDIAN_RANGE_M;
    if (lo..=hi).contains(&median) {
        return None;
    }
    let raw = median as f64 * depth_factor;
    // The common factor that puts the median nearest a typical indoor depth (by ratio).
    let hint = COMMON_FACTORS
        .iter()
        .map(|&f| (f, raw / f))
        .filter(|&(_, m)| (lo as f64..=hi as f64).contains(&m))
        .min_by(|a, b| {
            (a.1 / TYPICAL_DEPTH_M)
                .ln()
                .abs()
                .total_cmp(&(b.1 / TYPICAL_DEPTH_M).ln().abs())
        })
        .map(|(f, m)| format!("; with {f} it would be {m:.2} m"))
        .unwrap_or_default();
    Some(format!(
        "median depth {median:.2} m with depth factor {depth_factor}: RGB-D frames have a median \
         of about {lo}-{hi} m, so the factor is probably wrong{hint} (TUM, Bonn and ICL-NUIM use \
         5000, most others 1000: set DepthMapFactor / depth_factor in the settings)"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plausible_scene_passes_and_wrong_factors_are_named() {
        // A room 1-4 m deep, with holes (0) and NaN as real depth maps have.
        let mut room = DepthMetres::new(64, 48, 0.0);
        for y in 0..48 {
            for x in 0..64 {
                let z = match (x + y) % 7 {
                    0 => 0.0,
                    1 => f32::NAN,
                    k => 1.0 + k as f32 * 0.5,
                };
                room.set(x, y, z);
            }
        }
        assert_eq!(depth_scale_warning(&room, 5000.0), None);
        // The same raw values read with 1000 instead of 5000: 5x deeper.
        let mut deep = room.clone();
        let mut shallow = room.clone();
        for y in 0..48 {
            for x in 0..64 {
                deep.set(x, y, room.get(x, y) * 5.0);
                shallow.set(x, y, room.get(x, y) / 50.0);
            }
        }
        let w = depth_scale_warning(&deep, 1000.0).expect("5x too deep");
        assert!(w.contains("with 5000 it would be"), "{w}");
        let w = depth_scale_warning(&shallow, 50000.0).expect("50x too shallow");
        assert!(w.contains("with 1000 it would be"), "{w}");
        // Blank or nearly blank frames say nothing about the factor.
        assert_eq!(
            depth_scale_warning(&DepthMetres::new(64, 48, 0.0), 1.0),
            None
        );
        let mut speck = DepthMetres::new(64, 48, 0.0);
        speck.set(0, 0, 500.0);
        assert_eq!(depth_scale_warning(&speck, 1.0), None);
        assert_eq!(depth_scale_warning(&DepthMetres::new(0, 0, 0.0), 1.0), None);
    }
}
