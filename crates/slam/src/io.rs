//! The map out to files other tools read.

use std::io::Write;

use crate::data::map::Map;

/// Write the map's good points as an ASCII PLY point cloud (`x y z` in the map's frame, metres,
/// and how many keyframes observe each point), readable by MeshLab, CloudCompare, Open3D or
/// PCL. Returns how many points were written.
///
/// ```
/// let map = stillpoint_slam::data::map::Map::new();
/// let mut out = Vec::new();
/// assert_eq!(stillpoint_slam::io::write_map_points_ply(&map, &mut out).unwrap(), 0);
/// assert!(String::from_utf8(out).unwrap().starts_with("ply\n"));
/// ```
pub fn write_map_points_ply(map: &Map, mut w: impl Write) -> std::io::Result<usize> {
    let points: Vec<_> = map.points.values().filter(|p| !p.bad).collect();
    write!(
        w,
        "ply\nformat ascii 1.0\ncomment stillpoint sparse map\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property uint observations\nend_header\n",
        points.len()
    )?;
    for p in &points {
        writeln!(
            w,
            "{} {} {} {}",
            p.position.x as f32,
            p.position.y as f32,
            p.position.z as f32,
            p.observations.len()
        )?;
    }
    w.flush()?;
    Ok(points.len())
}
