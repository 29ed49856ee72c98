//! The living-room presets (`living_cross`, `living_close`, `living_turn`, `living_empty`): a
//! low-texture room (plain painted walls, a plain floor, a few sparse items that give a modest
//! number of corners), a hand-held camera (sums of sinusoids with seed-dependent phases) and one
//! richly textured person close to the camera who out-features the room, so that a two-frame
//! fundamental matrix tends to follow the person (the failure seen on photo-realistic
//! sequences). World frame as in [`crate::scene`]: x right, y into the room, z up.

use crate::mesh::{Mesh, P3};
use crate::presets::{CameraPath, Photos, Preset, Wave, pose_xy};
use crate::scene::{Motion, Outfit, Route, Scene, coco, person_parts};
use crate::texture::Style;
use rand::Rng;
use rand_pcg::Pcg64Mcg;
use std::f64::consts::PI;
use stillpoint_geometry::Se3;

/// Room bounds of the living room: x, y, z ranges (metres).
pub const LIVING_ROOM: [[f64; 2]; 3] = [[-2.3, 2.3], [-1.6, 2.9], [0.0, 2.6]];

/// Where the hand-held camera is held (before its sway) and what it looks at: the back wall
/// with the sofa, 3.85 m ahead, about 10 degrees down.
pub const LIVING_EYE: [f64; 3] = [0.0, -0.95, 1.45];
/// The point the hand-held camera looks at: low on the back wall, above the sofa.
pub const LIVING_TARGET: [f64; 3] = [0.0, 2.9, 0.75];

/// Build a living-room preset. Random draws, in order: the room's textures, the camera's
/// phases, the person's route, the person's outfit (only without photos), so that `--textures`
/// changes the person alone.
pub fn build(preset: Preset, rng: &mut Pcg64Mcg, photos: &Photos) -> (Scene, CameraPath) {
    let mut s = Scene::new();
    furnish_living(&mut s, rng);
    let cam = handheld(preset == Preset::LivingTurn, rng);
    let route = match preset {
        Preset::LivingCross => Some(cross_route(rng)),
        Preset::LivingClose => Some(close_route(rng)),
        Preset::LivingTurn => Some(turn_route(rng)),
        _ => None,
    };
    if let Some(route) = route {
        add_person(&mut s, rng, photos, route);
    }
    (s, cam)
}

/// The hand-held camera: a slow sway with a faster shake on every axis. Peaks: ~0.3 m/s and
/// ~25 deg/s; with `fast_turn` the yaw swings +-26 deg every 5 s (peaks ~50 deg/s).
fn handheld(fast_turn: bool, rng: &mut Pcg64Mcg) -> CameraPath {
    let d = |x: f64| x.to_radians();
    let pos = [
        vec![
            Wave::random(rng, 0.15, 9.0),
            Wave::random(rng, 0.03, 2.3),
            Wave::random(rng, 0.004, 0.7),
        ],
        vec![Wave::random(rng, 0.08, 7.0), Wave::random(rng, 0.015, 1.9)],
        vec![
            Wave::random(rng, 0.03, 3.3),
            Wave::random(rng, 0.006, 1.1),
            Wave::random(rng, 0.003, 0.55),
        ],
    ];
    let yaw = if fast_turn {
        vec![
            Wave::random(rng, d(26.0), 5.0),
            Wave::random(rng, d(3.0), 1.5),
            Wave::random(rng, d(0.5), 0.45),
        ]
    } else {
        vec![
            Wave::random(rng, d(7.0), 7.0),
            Wave::random(rng, d(2.5), 2.1),
            Wave::random(rng, d(0.5), 0.5),
        ]
    };
    let rot = [
        yaw,
        vec![
            Wave::random(rng, d(4.0), 6.0),
            Wave::random(rng, d(1.2), 1.7),
            Wave::random(rng, d(0.4), 0.45),
        ],
        vec![
            Wave::random(rng, d(2.5), 8.0),
            Wave::random(rng, d(0.8), 2.3),
            Wave::random(rng, d(0.3), 0.6),
        ],
    ];
    CameraPath::Handheld {
        base: P3::from(LIVING_EYE),
        target: P3::from(LIVING_TARGET),
        pos,
        rot,
    }
}

/// Builds a route from waypoints, stops and walking speed. The walker stands at the first
/// waypoint (behind the camera, unseen) until `start`, and stays at the last one (also unseen)
/// to the end of the sequence.
struct RouteBuilder {
    points: Vec<[f64; 2]>,
    dwell: Vec<f64>,
}

impl RouteBuilder {
    fn new(from: [f64; 2]) -> Self {
        RouteBuilder {
            points: vec![from],
            dwell: vec![0.0],
        }
    }

    fn to(&mut self, p: [f64; 2]) -> &mut Self {
        self.points.push(p);
        self.dwell.push(0.0);
        self
    }

    /// Walk to `p`, turn on the spot towards `face` (a direction) over `turn` seconds, stand
    /// still `still` seconds, then turn towards the next waypoint over `turn` seconds.
    fn stop(&mut self, p: [f64; 2], face: [f64; 2], turn: f64, still: f64) -> &mut Self {
        let n = (face[0] * face[0] + face[1] * face[1]).sqrt().max(1e-9);
        // two 1 mm steps in the facing direction: the heading in between is `face`, so the
        // middle dwell is a still stand (a walker turns during a dwell from the incoming to the
        // outgoing heading)
        let step = |k: f64| [p[0] + k * 1e-3 * face[0] / n, p[1] + k * 1e-3 * face[1] / n];
        self.points.extend([p, step(1.0), step(2.0)]);
        self.dwell.extend([turn, still, turn]);
        self
    }

    fn finish(&mut self, speed: f64, start: f64) -> Route {
        const WAIT: f64 = 60.0;
        self.dwell[0] = WAIT;
        *self.dwell.last_mut().expect("a route has points") = WAIT;
        Route {
            points: self.points.clone(),
            dwell: self.dwell.clone(),
            speed,
            offset: WAIT - start,
        }
    }
}

/// Camera-plane y of the hidden start and end points (behind the camera, which is at y -0.95).
const HIDDEN_Y: f64 = -1.3;

/// Depth (along y from the camera's resting point) to world y.
fn at_depth(d: f64) -> f64 {
    LIVING_EYE[1] + d
}

/// living_cross: in from one side behind the camera, across the view 1.0-1.5 m ahead, a stop
/// of 1.4-2.2 s (turns included), and back out the same side on a closer line (0.8-1.1 m).
fn cross_route(rng: &mut Pcg64Mcg) -> Route {
    let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let start = rng.random_range(0.5..3.0);
    let speed = rng.random_range(0.9..1.2);
    let d1 = rng.random_range(1.0..1.5);
    let d2 = rng.random_range(0.8..1.1);
    let x_stop = rng.random_range(0.1..0.5);
    let still = rng.random_range(0.6..1.4);
    let mut r = RouteBuilder::new([-1.9 * side, HIDDEN_Y]);
    r.to([-side, at_depth(d1)])
        .stop([x_stop * side, at_depth(d1)], [0.0, -1.0], 0.4, still)
        .to([-side, at_depth(d2)])
        .to([-1.9 * side, HIDDEN_Y + 0.1]);
    r.finish(speed, start)
}

/// living_close: in from one side, a stop ~1.1 m ahead facing the camera, a few steps to a
/// stop ~0.8 m ahead, across to the other half (~0.95 m), a stop, back a little (~1.3 m) and
/// out the other side.
fn close_route(rng: &mut Pcg64Mcg) -> Route {
    let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let start = rng.random_range(0.3..1.5);
    let speed = rng.random_range(0.8..1.0);
    let mut j = |a: f64| rng.random_range(-a..a);
    let p1 = [(-0.1 + j(0.15)) * side, at_depth(1.1 + j(0.1))];
    let p2 = [(0.35 + j(0.1)) * side, at_depth(0.8 + j(0.05))];
    let p3 = [(-0.35 + j(0.1)) * side, at_depth(0.95 + j(0.1))];
    let p4 = [(0.1 + j(0.15)) * side, at_depth(1.3 + j(0.15))];
    let face = [0.0, -1.0];
    let mut r = RouteBuilder::new([-1.7 * side, HIDDEN_Y]);
    r.stop(p1, face, 0.5, rng.random_range(0.5..1.2))
        .stop(p2, [0.3 * side, -1.0], 0.4, rng.random_range(0.3..0.8))
        .stop(p3, face, 0.5, rng.random_range(0.6..1.3))
        .stop(p4, [-0.3 * side, -1.0], 0.4, rng.random_range(0.3..0.8))
        .to([1.8 * side, HIDDEN_Y]);
    r.finish(speed, start)
}

/// living_turn: one brisk crossing 1.4-2.1 m ahead, in from behind the camera on one side and
/// out behind it on the other.
fn turn_route(rng: &mut Pcg64Mcg) -> Route {
    let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let start = rng.random_range(0.5..3.0);
    let speed = rng.random_range(0.9..1.15);
    let d = rng.random_range(1.4..1.9);
    let mut r = RouteBuilder::new([-2.0 * side, HIDDEN_Y]);
    r.to([-1.1 * side, at_depth(d)])
        .to([1.1 * side, at_depth(d + 0.2)])
        .to([2.0 * side, HIDDEN_Y]);
    r.finish(speed, start)
}

/// Height of the photographed cut-out (m): a standing adult's, taller than the other presets'
/// [`crate::presets::BILLBOARD_HEIGHT`] (their cut-out of a seated man scaled to a walker
/// looked small next to the camera).
const CUTOUT_HEIGHT: f64 = 1.7;

/// The person: the photographed cut-out when `--textures` gave one (a billboard turned to the
/// camera), else an articulated person in a loud shirt and textured trousers.
fn add_person(s: &mut Scene, rng: &mut Pcg64Mcg, photos: &Photos, route: Route) {
    if let Some(p) = photos.people.first() {
        crate::presets::add_cutout_walker(s, p, "walker", CUTOUT_HEIGHT, route);
        return;
    }
    let o = textured_outfit(s, rng);
    s.add(
        "walker",
        Some(coco::PERSON),
        person_parts(&o),
        Motion::Walker {
            route,
            carry_until: 0.0,
        },
    );
}

/// A loud outfit: a plaid or flowered shirt, jeans or camouflage trousers (high contrast, so
/// the person holds many ORB corners, as a real person in patterned clothes does).
fn textured_outfit(s: &mut Scene, rng: &mut Pcg64Mcg) -> Outfit {
    let plaids = [
        ([0.7, 0.12, 0.1], [0.08, 0.08, 0.1]),
        ([0.2, 0.3, 0.6], [0.9, 0.9, 0.88]),
        ([0.25, 0.45, 0.3], [0.1, 0.12, 0.3]),
        ([0.85, 0.85, 0.8], [0.3, 0.45, 0.25]),
    ];
    let shirt = if rng.random_bool(0.7) {
        let (a, b) = plaids[rng.random_range(0..plaids.len())];
        Style::Plaid(a, b)
    } else {
        let bases = [[0.1, 0.12, 0.3], [0.92, 0.9, 0.85], [0.08, 0.08, 0.08]];
        Style::Floral(bases[rng.random_range(0..bases.len())])
    };
    let trousers = if rng.random_bool(0.6) {
        Style::Denim([0.2, 0.28, 0.48])
    } else {
        Style::Camo
    };
    let skins = [
        [0.87, 0.7, 0.58],
        [0.62, 0.45, 0.33],
        [0.95, 0.8, 0.7],
        [0.45, 0.3, 0.22],
    ];
    let hairs = [[0.2, 0.14, 0.08], [0.05, 0.05, 0.05], [0.6, 0.45, 0.25]];
    let skin = skins[rng.random_range(0..skins.len())];
    let hair = hairs[rng.random_range(0..hairs.len())];
    Outfit {
        shirt: s.paint(shirt, 512, 256, rng),
        trousers: s.paint(trousers, 256, 256, rng),
        skin: s.paint(Style::Skin(skin), 64, 64, rng),
        head: s.paint(Style::Head(skin, hair), 128, 128, rng),
        hair: s.paint(Style::Cloth(hair), 64, 64, rng),
        shoes: s.paint(Style::Plain([0.12, 0.1, 0.09]), 32, 32, rng),
    }
}

/// A sofa (or armchair) `w` wide, `d` deep, origin at the floor centre, its back at +y (it
/// faces -y): a base, a back, two arms, seat cushions, two throw pillows and short legs.
fn sofa_mesh(w: f64, d: f64, fabric: u16, cushion: u16, pillow: u16, legs: u16) -> Mesh {
    let v = P3::new;
    let (hw, hd) = (w / 2.0, d / 2.0);
    let arm = 0.17;
    let mut m = Mesh::cuboid(v(-hw, -hd, 0.1), v(hw, hd, 0.4), fabric);
    m.extend(Mesh::cuboid(v(-hw, hd - 0.2, 0.4), v(hw, hd, 0.85), fabric));
    m.extend(Mesh::cuboid(
        v(-hw, -hd, 0.4),
        v(-hw + arm, hd - 0.2, 0.62),
        fabric,
    ));
    m.extend(Mesh::cuboid(
        v(hw - arm, -hd, 0.4),
        v(hw, hd - 0.2, 0.62),
        fabric,
    ));
    let inner = w - 2.0 * arm;
    let n = if inner > 1.2 { 3 } else { 1 };
    for k in 0..n {
        let x0 = -hw + arm + inner * k as f64 / n as f64 + 0.008;
        let x1 = -hw + arm + inner * (k + 1) as f64 / n as f64 - 0.008;
        m.extend(Mesh::cuboid(
            v(x0, -hd - 0.02, 0.4),
            v(x1, hd - 0.2, 0.52),
            cushion,
        ));
    }
    if pillow != fabric && n > 1 {
        for (x, tilt) in [(-hw + arm + 0.25, 0.3), (hw - arm - 0.25, -0.25)] {
            let p = Mesh::cuboid(v(-0.2, -0.07, -0.2), v(0.2, 0.07, 0.2), pillow);
            let pose = pose_xy(x, hd - 0.32, 0.72, tilt)
                * nalgebra::Isometry3::rotation(nalgebra::Vector3::x() * -0.25);
            m.extend(p.transformed(&pose));
        }
    }
    for (x, y) in [(-hw + 0.06, -hd + 0.06), (hw - 0.06, -hd + 0.06)] {
        m.extend(Mesh::cuboid(
            v(x - 0.025, y - 0.025, 0.0),
            v(x + 0.025, y + 0.025, 0.1),
            legs,
        ));
    }
    m
}

/// A door in a wall facing -y at y = 0 (origin at the floor centre of the opening): a panel
/// flush with the wall, a frame of three moulded strips, and a handle.
fn door_mesh(w: f64, h: f64, frame: u16, panel: u16, handle: u16) -> Mesh {
    let v = P3::new;
    let f = 0.07;
    let mut m = Mesh::default();
    m.quad(
        [
            v(-w / 2.0, -0.005, 0.0),
            v(w / 2.0, -0.005, 0.0),
            v(w / 2.0, -0.005, h),
            v(-w / 2.0, -0.005, h),
        ],
        panel,
        [0.0, 0.0],
        [1.0, 1.0],
    );
    m.extend(Mesh::cuboid(
        v(-w / 2.0 - f, -0.02, 0.0),
        v(-w / 2.0, 0.0, h + f),
        frame,
    ));
    m.extend(Mesh::cuboid(
        v(w / 2.0, -0.02, 0.0),
        v(w / 2.0 + f, 0.0, h + f),
        frame,
    ));
    m.extend(Mesh::cuboid(
        v(-w / 2.0, -0.02, h),
        v(w / 2.0, 0.0, h + f),
        frame,
    ));
    m.extend(Mesh::cuboid(
        v(w / 2.0 - 0.12, -0.07, 0.98),
        v(w / 2.0 - 0.02, -0.05, 1.01),
        handle,
    ));
    m
}

/// A framed picture hung on a wall facing -y (origin at its centre, on the wall).
fn picture_mesh(w: f64, h: f64, canvas: u16, frame: u16) -> Mesh {
    let v = P3::new;
    let mut m = Mesh::cuboid(
        v(-w / 2.0, -0.025, -h / 2.0),
        v(w / 2.0, 0.0, h / 2.0),
        frame,
    );
    m.quad(
        [
            v(-w / 2.0, -0.026, -h / 2.0),
            v(w / 2.0, -0.026, -h / 2.0),
            v(w / 2.0, -0.026, h / 2.0),
            v(-w / 2.0, -0.026, h / 2.0),
        ],
        canvas,
        [0.0, 0.0],
        [1.0, 1.0],
    );
    m
}

/// The living room: plain painted walls and ceiling, a plain carpet, skirting boards, and a
/// few sparse things: a sofa with a painting above it, a door, a plant, a rug, and a sideboard
/// with a small picture on the left wall (in view when the camera turns). The room alone gives
/// ~450-650 ORB keypoints per frame (1000 asked for): every item fills several pyramid levels
/// with corners, and fewer than ~500 would keep the RGB-D initialisation from starting; a
/// coffee table and an armchair (each +50-100) were taken out for that reason.
fn furnish_living(s: &mut Scene, rng: &mut Pcg64Mcg) {
    let [[x0, x1], [y0, y1], _] = LIVING_ROOM;
    let v = P3::new;
    let wall_colours = [
        [0.86, 0.83, 0.76],
        [0.8, 0.82, 0.8],
        [0.84, 0.8, 0.74],
        [0.82, 0.82, 0.78],
    ];
    let floor = s.paint(Style::Carpet([0.55, 0.5, 0.44]), 1024, 1024, rng);
    let ceiling = s.paint(Style::Paint([0.93, 0.93, 0.91]), 256, 256, rng);
    let walls = wall_colours.map(|c| s.paint(Style::Paint(c), 1024, 512, rng));
    let mut room = crate::presets::box_room(LIVING_ROOM, floor, ceiling, walls);
    // skirting boards, a shade lighter than the walls
    let skirt = s.paint(Style::Paint([0.92, 0.91, 0.88]), 256, 32, rng);
    let (sk, sd) = (0.08, 0.015);
    room.extend(Mesh::cuboid(v(x0, y1 - sd, 0.0), v(x1, y1, sk), skirt));
    room.extend(Mesh::cuboid(v(x0, y0, 0.0), v(x0 + sd, y1, sk), skirt));
    room.extend(Mesh::cuboid(v(x1 - sd, y0, 0.0), v(x1, y1, sk), skirt));
    room.extend(Mesh::cuboid(v(x0, y0, 0.0), v(x1, y0 + sd, sk), skirt));
    s.add_static("room", None, room, Se3::identity());

    // the sofa against the back wall, a painting above it
    let fabric = s.paint(Style::Upholstery([0.45, 0.47, 0.5]), 512, 256, rng);
    let cushion = s.paint(Style::Upholstery([0.5, 0.52, 0.55]), 256, 128, rng);
    let dark = s.paint(Style::Plain([0.2, 0.17, 0.15]), 32, 32, rng);
    s.add_static(
        "sofa",
        Some(coco::COUCH),
        sofa_mesh(2.0, 0.85, fabric, cushion, fabric, dark),
        pose_xy(-0.35, y1 - 0.43, 0.0, 0.0),
    );
    let painting = s.paint(Style::Painting, 384, 256, rng);
    let frame = s.paint(Style::Grain([0.62, 0.5, 0.38]), 64, 64, rng);
    s.add_static(
        "picture",
        None,
        picture_mesh(0.84, 0.56, painting, frame),
        pose_xy(-0.35, y1, 1.55, 0.0),
    );
    // a door on the right of the back wall
    let jamb = s.paint(Style::Paint([0.95, 0.95, 0.93]), 64, 256, rng);
    let panel = s.paint(Style::Panel([0.9, 0.89, 0.86]), 128, 256, rng);
    let brass = s.paint(Style::Plain([0.6, 0.52, 0.3]), 16, 16, rng);
    s.add_static(
        "door",
        None,
        door_mesh(0.84, 2.02, jamb, panel, brass),
        pose_xy(1.55, y1, 0.0, 0.0),
    );
    // a plant in the back left corner
    let pot = s.paint(Style::Plain([0.62, 0.42, 0.3]), 64, 64, rng);
    let leaves = s.paint(Style::Upholstery([0.25, 0.4, 0.2]), 256, 128, rng);
    let mut plant =
        Mesh::prism(10, [0.13, 0.13], [0.1, 0.1], 0.3, pot).translated(P3::new(0.0, 0.0, 0.3));
    plant.extend(
        Mesh::ellipsoid(P3::new(0.2, 0.2, 0.3), 6, 10, leaves).translated(P3::new(0.0, 0.0, 0.6)),
    );
    s.add_static(
        "plant",
        Some(coco::POTTED_PLANT),
        plant,
        pose_xy(-1.85, y1 - 0.45, 0.0, 0.3),
    );
    // a rug in front of the sofa
    let rug_tex = s.paint(
        Style::Rug([0.58, 0.52, 0.45], [0.5, 0.44, 0.4]),
        512,
        384,
        rng,
    );
    let mut rug = Mesh::default();
    rug.quad(
        [
            v(-1.1, -0.75, 0.004),
            v(1.1, -0.75, 0.004),
            v(1.1, 0.75, 0.004),
            v(-1.1, 0.75, 0.004),
        ],
        rug_tex,
        [0.0, 0.0],
        [1.0, 1.0],
    );
    s.add_static("rug", None, rug, pose_xy(-0.3, 1.45, 0.0, 0.0));
    // a sideboard on the left wall with a small picture above it
    let front = s.paint(Style::Panel([0.78, 0.74, 0.68]), 256, 128, rng);
    s.add_static(
        "sideboard",
        None,
        Mesh::cuboid(P3::new(-0.7, -0.22, 0.0), P3::new(0.7, 0.22, 0.8), front),
        pose_xy(x0 + 0.23, 1.3, 0.0, PI / 2.0),
    );
    let small = s.paint(Style::Painting, 192, 256, rng);
    s.add_static(
        "picture",
        None,
        picture_mesh(0.36, 0.48, small, frame),
        pose_xy(x0, 1.3, 1.45, PI / 2.0),
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn sample(preset: Preset, seed: u64) -> (Scene, CameraPath) {
        build(
            preset,
            &mut Pcg64Mcg::seed_from_u64(seed),
            &Photos::default(),
        )
    }

    #[test]
    fn handheld_camera_stays_in_the_room_within_its_speed_limits() {
        for (preset, max_deg) in [(Preset::LivingCross, 32.0), (Preset::LivingTurn, 62.0)] {
            for seed in 0..5 {
                let (_, cam) = sample(preset, seed);
                let (mut v_max, mut w_max): (f64, f64) = (0.0, 0.0);
                for k in 0..300 {
                    let (a, b) = (cam.pose(k as f64 / 30.0), cam.pose((k + 1) as f64 / 30.0));
                    v_max = v_max.max((b.translation.vector - a.translation.vector).norm() * 30.0);
                    w_max = w_max.max(a.rotation.angle_to(&b.rotation).to_degrees() * 30.0);
                    let p = a.translation.vector;
                    for d in 0..3 {
                        assert!(p[d] > LIVING_ROOM[d][0] + 0.3 && p[d] < LIVING_ROOM[d][1] - 0.3);
                    }
                    // looking into the room, not at the floor or ceiling alone
                    let fwd = a.rotation * P3::z();
                    assert!(fwd.y > 0.7 && fwd.z.abs() < 0.45, "{preset:?} {fwd:?}");
                }
                eprintln!("{preset:?} seed {seed}: {v_max:.2} m/s, {w_max:.1} deg/s");
                assert!(v_max < 0.36, "{preset:?} seed {seed}: {v_max} m/s");
                assert!(w_max < max_deg, "{preset:?} seed {seed}: {w_max} deg/s");
                if preset == Preset::LivingTurn {
                    assert!(w_max > 38.0, "living_turn seed {seed}: only {w_max} deg/s");
                }
            }
        }
    }

    #[test]
    fn seeds_change_the_route_and_the_camera() {
        let state = |seed| {
            let (s, cam) = sample(Preset::LivingCross, seed);
            let o = s.objects.last().unwrap();
            let Motion::Walker { route, .. } = &o.motion else {
                panic!("a walker")
            };
            (route.state(3.0).pos, cam.pose(1.0).translation.vector)
        };
        let (a, b) = (state(0), state(1));
        assert!(a.0 != b.0 && a.1 != b.1);
        assert!(
            sample(Preset::LivingEmpty, 0)
                .0
                .objects
                .iter()
                .all(|o| o.class_id != Some(coco::PERSON))
        );
    }
}
