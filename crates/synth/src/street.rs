//! The street preset (`street`): a car-mounted camera driving down a straight town street
//! (KITTI-like: 1.65 m up, looking ahead), past parked cars, behind a car in its own lane,
//! meeting oncoming traffic, with a pedestrian on the pavement. Forward motion puts the
//! epipole inside the image, where the two-frame epipolar check is weakest, and the car ahead
//! moves along the epipolar lines: the failure a driving sequence brings. World frame as in
//! [`crate::scene`]: x right, y along the street (the direction of travel), z up.

use crate::mesh::{Mesh, P3};
use crate::presets::{CameraPath, Photos, Wave, pose_xy};
use crate::scene::{Motion, Route, Scene, coco, person_parts};
use crate::texture::{Canvas, Style, random_colour};
use rand::Rng;
use rand_pcg::Pcg64Mcg;
use std::f64::consts::PI;

/// Half the width of the two driving lanes (m): lane centres at +-`LANE / 2`.
pub const LANE: f64 = 3.5;
/// Where the parking lanes end and the pavements begin (|x|, m).
pub const KERB: f64 = 5.6;
/// Where the façades stand (|x|, m, before each building's own setback).
pub const FACADE: f64 = 8.2;
/// The street's extent along y (m): the camera drives from y = 0.
pub const STREET_Y: [f64; 2] = [-15.0, 170.0];
/// The camera's height above the road (KITTI's: 1.65 m).
pub const CAMERA_HEIGHT: f64 = 1.65;
/// COCO's car class.
pub const CAR: u16 = 2;

/// Build the street. Random draws, in order: the road and pavements, the buildings, the
/// parked cars, the camera, the moving cars, the pedestrian.
pub fn build(rng: &mut Pcg64Mcg, photos: &Photos) -> (Scene, CameraPath) {
    let mut s = Scene::new();
    pave(&mut s, rng);
    for side in [-1.0, 1.0] {
        buildings(&mut s, rng, side);
    }
    street_furniture(&mut s, rng);
    for side in [-1.0, 1.0] {
        parked_cars(&mut s, rng, side);
    }
    let speed = rng.random_range(5.0..7.0);
    let cam = drive(rng, speed);
    traffic(&mut s, rng, speed);
    pedestrian(&mut s, rng, photos);
    (s, cam)
}

/// The camera: along the right lane at `speed` m/s, 4 degrees down, with a gentle weave in the
/// lane and the pitch and roll of a car on an uneven road.
fn drive(rng: &mut Pcg64Mcg, speed: f64) -> CameraPath {
    let d = |x: f64| x.to_radians();
    CameraPath::Drive {
        start: P3::new(LANE / 2.0, 0.0, CAMERA_HEIGHT),
        speed,
        pitch: d(4.0),
        sway: vec![Wave::random(rng, 0.15, 7.0), Wave::random(rng, 0.03, 2.5)],
        bounce: vec![Wave::random(rng, 0.01, 0.8), Wave::random(rng, 0.005, 0.35)],
        rot: [
            vec![
                Wave::random(rng, d(1.0), 7.0),
                Wave::random(rng, d(0.3), 2.1),
            ],
            vec![
                Wave::random(rng, d(0.4), 1.3),
                Wave::random(rng, d(0.2), 0.5),
            ],
            vec![
                Wave::random(rng, d(0.4), 2.7),
                Wave::random(rng, d(0.15), 0.9),
            ],
        ],
    }
}

/// Asphalt with faint patches and cracks; the lane markings are painted by the caller.
fn asphalt(rng: &mut Pcg64Mcg, w: usize, h: usize) -> Canvas {
    let g = rng.random_range(0.28..0.36f32);
    let mut c = Canvas::new(w, h, [g, g, g * 1.03]);
    c.fbm(rng, 48.0, 0.12);
    c.value_noise(rng, 2.0, 0.1, 1.0);
    for _ in 0..rng.random_range(4..10) {
        let (x, y) = (
            rng.random_range(0.0..w as f32),
            rng.random_range(0.0..h as f32),
        );
        let r = rng.random_range(4.0..18.0);
        let d = rng.random_range(0.6..0.85);
        c.ellipse(x, y, r, r * 0.6, [g * d, g * d, g * d], 0.6);
    }
    c
}

/// The road (tiles 10 m long, each its own asphalt, with a dashed centre line and solid lines
/// between the driving and parking lanes), kerbs and paving.
fn pave(s: &mut Scene, rng: &mut Pcg64Mcg) {
    let v = P3::new;
    let mut road = Mesh::default();
    let tile = 10.0;
    let n = ((STREET_Y[1] - STREET_Y[0]) / tile).ceil() as usize;
    // The road texture spans x in [-KERB, KERB]: u = (x + KERB) / (2 KERB).
    let (w, h) = (448, 256);
    let u_of = |x: f64| ((x + KERB) / (2.0 * KERB) * w as f64) as f32;
    let white = [0.85, 0.85, 0.82];
    let mut tiles = Vec::new();
    for _ in 0..4 {
        let mut c = asphalt(rng, w, h);
        // dashed centre line: 3 m of paint in a 10 m tile (v runs along y)
        c.rect(u_of(-0.06), 0.0, u_of(0.06), 0.3 * h as f32, white, 1.0);
        for side in [-1.0, 1.0] {
            let x = side * LANE;
            c.rect(u_of(x - 0.06), 0.0, u_of(x + 0.06), h as f32, white, 0.9);
            // parking bay ticks
            let x2 = side * (KERB - 0.3);
            c.rect(
                u_of(x.min(x2)),
                0.48 * h as f32,
                u_of(x.max(x2)),
                0.5 * h as f32,
                white,
                0.7,
            );
        }
        tiles.push(s.add_texture(c.into_texture()));
    }
    for k in 0..n {
        let (y0, y1) = (
            STREET_Y[0] + k as f64 * tile,
            STREET_Y[0] + (k + 1) as f64 * tile,
        );
        let tex = tiles[rng.random_range(0..tiles.len())];
        road.quad(
            [
                v(-KERB, y0, 0.0),
                v(KERB, y0, 0.0),
                v(KERB, y1, 0.0),
                v(-KERB, y1, 0.0),
            ],
            tex,
            [0.0, 0.0],
            [1.0, 1.0],
        );
    }
    s.add_static("road", None, road, pose_xy(0.0, 0.0, 0.0, 0.0));

    let mut walk = Mesh::default();
    let slabs: Vec<u16> = (0..3)
        .map(|_| {
            let g = rng.random_range(0.55..0.68f32);
            let mut c = Canvas::new(256, 256, [g, g * 0.98, g * 0.94]);
            c.fbm(rng, 32.0, 0.08);
            // a paving-slab grid, 1 m slabs (the texture spans 2.6 m x 10 m)
            let dark = [g * 0.7, g * 0.7, g * 0.68];
            for i in 0..10 {
                let y = i as f32 * 25.6;
                c.rect(0.0, y, 256.0, y + 1.5, dark, 0.8);
            }
            for i in 0..3 {
                let x = i as f32 * 98.0;
                c.rect(x, 0.0, x + 1.5, 256.0, dark, 0.8);
            }
            c.into_texture()
        })
        .map(|t| s.add_texture(t))
        .collect();
    let kerb_tex = s.paint(Style::Plain([0.62, 0.62, 0.6]), 64, 16, rng);
    let kerb_h = 0.12;
    for side in [-1.0f64, 1.0] {
        let (xa, xb) = (side * KERB, side * (FACADE + 2.0));
        let (x0, x1) = (xa.min(xb), xa.max(xb));
        for k in 0..n {
            let (y0, y1) = (
                STREET_Y[0] + k as f64 * tile,
                STREET_Y[0] + (k + 1) as f64 * tile,
            );
            let tex = slabs[rng.random_range(0..slabs.len())];
            walk.quad(
                [
                    v(x0, y0, kerb_h),
                    v(x1, y0, kerb_h),
                    v(x1, y1, kerb_h),
                    v(x0, y1, kerb_h),
                ],
                tex,
                [0.0, 0.0],
                [1.0, 1.0],
            );
            // the kerb's face, towards the road
            let x = side * KERB;
            let face = if side > 0.0 {
                [
                    v(x, y1, 0.0),
                    v(x, y0, 0.0),
                    v(x, y0, kerb_h),
                    v(x, y1, kerb_h),
                ]
            } else {
                [
                    v(x, y0, 0.0),
                    v(x, y1, 0.0),
                    v(x, y1, kerb_h),
                    v(x, y0, kerb_h),
                ]
            };
            walk.quad(face, kerb_tex, [0.0, 0.0], [1.0, 1.0]);
        }
    }
    s.add_static("pavement", None, walk, pose_xy(0.0, 0.0, 0.0, 0.0));
}

/// A façade `w` x `h` metres: rendered plaster or brick with rows of windows (frames, dark
/// glass with reflections, some blinds), a shop front on the ground floor.
fn facade(rng: &mut Pcg64Mcg, w: f64, h: f64) -> Canvas {
    let px_per_m = 40.0;
    let (cw, ch) = (
        ((w * px_per_m) as usize).clamp(64, 1024),
        ((h * px_per_m) as usize).clamp(64, 1024),
    );
    let (sx, sy) = (cw as f32 / w as f32, ch as f32 / h as f32);
    let plaster = [
        [0.82, 0.76, 0.64],
        [0.7, 0.42, 0.32],
        [0.78, 0.78, 0.74],
        [0.6, 0.62, 0.66],
        [0.86, 0.82, 0.7],
        [0.55, 0.36, 0.3],
    ];
    let base = plaster[rng.random_range(0..plaster.len())];
    let mut c = Canvas::new(cw, ch, base);
    c.fbm(rng, 64.0, 0.1);
    c.value_noise(rng, 3.0, 0.06, 1.0);
    let frame = if rng.random_bool(0.5) {
        [0.92, 0.92, 0.9]
    } else {
        [0.25, 0.22, 0.2]
    };
    let floor_h = rng.random_range(2.9..3.4);
    let bay = rng.random_range(2.2..3.2);
    let (win_w, win_h) = (rng.random_range(0.9..1.4), rng.random_range(1.3..1.7));
    let floors = ((h - 0.5) / floor_h) as usize;
    let bays = ((w - 0.6) / bay).max(1.0) as usize;
    let margin = (w - bays as f64 * bay) / 2.0;
    // v runs down the façade: row 0 is the top.
    let to_px = |x: f64, z: f64| ((x * sx as f64) as f32, ((h - z) * sy as f64) as f32);
    for f in 1..floors {
        // a cornice line under each upper floor
        let (_, y) = to_px(0.0, f as f64 * floor_h - 0.1);
        let shade = [base[0] * 0.8, base[1] * 0.8, base[2] * 0.8];
        c.rect(0.0, y, cw as f32, y + 0.12 * sy, shade, 0.8);
        for b in 0..bays {
            let xc = margin + (b as f64 + 0.5) * bay;
            let z0 = f as f64 * floor_h + 0.9;
            let (x0, y1) = to_px(xc - win_w / 2.0, z0);
            let (x1, y0) = to_px(xc + win_w / 2.0, z0 + win_h);
            let t = 0.1 * sx;
            c.rect(x0 - t, y0 - t, x1 + t, y1 + t, frame, 1.0);
            let g = rng.random_range(0.08..0.25f32);
            c.rect(x0, y0, x1, y1, [g, g * 1.05, g * 1.15], 1.0);
            // a reflection band, a mullion, sometimes a blind half down
            let r = rng.random_range(0.0..1.0f32);
            c.rect(
                x0,
                y0 + r * (y1 - y0) * 0.6,
                x1,
                y0 + (r * 0.6 + 0.15) * (y1 - y0),
                [0.5, 0.55, 0.6],
                0.35,
            );
            c.rect(
                (x0 + x1) / 2.0 - t / 2.0,
                y0,
                (x0 + x1) / 2.0 + t / 2.0,
                y1,
                frame,
                1.0,
            );
            if rng.random_bool(0.3) {
                let blind = random_colour(rng);
                c.rect(
                    x0,
                    y0,
                    x1,
                    y0 + rng.random_range(0.2..0.6) * (y1 - y0),
                    blind,
                    0.9,
                );
            }
        }
    }
    // the ground floor: a shop window or two and a door
    let (_, y_top) = to_px(0.0, 2.6);
    let (_, y_bot) = to_px(0.0, 0.1);
    let sign = random_colour(rng);
    c.rect(
        0.05 * cw as f32,
        y_top - 0.5 * sy,
        0.95 * cw as f32,
        y_top - 0.05 * sy,
        sign,
        1.0,
    );
    c.text(
        rng,
        [
            0.1 * cw as f32,
            y_top - 0.45 * sy,
            0.6 * cw as f32,
            y_top - 0.1 * sy,
        ],
        0.3 * sy,
        [0.95, 0.95, 0.92],
    );
    let door_x = rng.random_range(0.15..0.8) * cw as f32;
    c.rect(
        door_x,
        y_top + 0.3 * sy,
        door_x + 1.0 * sx,
        y_bot,
        [0.3, 0.2, 0.15],
        1.0,
    );
    for (a, b) in [
        (0.06, door_x / cw as f32 - 0.04),
        (door_x / cw as f32 + 1.0 * sx / cw as f32 + 0.04, 0.94),
    ] {
        if b - a < 0.05 {
            continue;
        }
        let g = rng.random_range(0.1..0.2f32);
        c.rect(
            a * cw as f32,
            y_top + 0.2 * sy,
            b * cw as f32,
            y_bot - 0.5 * sy,
            [g, g, g * 1.1],
            1.0,
        );
        // goods behind the glass
        let (gx0, gx1) = (a * cw as f32, b * cw as f32);
        for _ in 0..((gx1 - gx0) / (0.3 * sx)) as usize {
            let x = rng.random_range(gx0..gx1);
            let y = rng.random_range(y_bot - 1.4 * sy..y_bot - 0.7 * sy);
            let (gw, gh) = (
                rng.random_range(0.1..0.3) * sx,
                rng.random_range(0.1..0.4) * sy,
            );
            c.rect(x, y, (x + gw).min(gx1), y + gh, random_colour(rng), 0.8);
        }
    }
    c
}

/// The buildings along one side (`side` -1 left, +1 right): blocks 7-16 m long and 6-16 m
/// tall, each set back 0-1.5 m, with a façade of its own.
fn buildings(s: &mut Scene, rng: &mut Pcg64Mcg, side: f64) {
    let mut y = STREET_Y[0];
    let mut k = 0;
    while y < STREET_Y[1] {
        let len = rng.random_range(7.0..16.0);
        let height = rng.random_range(6.0..16.0);
        let setback = if rng.random_bool(0.3) {
            rng.random_range(0.5..1.5)
        } else {
            0.0
        };
        let x_front = side * (FACADE + setback);
        let x_back = side * (FACADE + setback + 10.0);
        let body_tex = s.paint(Style::Paint([0.7, 0.68, 0.64]), 64, 64, rng);
        let lo = P3::new(x_front.min(x_back), y, 0.0);
        let hi = P3::new(x_front.max(x_back), y + len, height);
        let mut m = Mesh::cuboid(lo, hi, body_tex);
        let tex = s.add_texture(facade(rng, len, height).into_texture());
        // the façade, a centimetre in front of the block, facing the street
        let x = x_front - side * 0.01;
        let v = P3::new;
        let q = if side > 0.0 {
            [
                v(x, y, 0.0),
                v(x, y + len, 0.0),
                v(x, y + len, height),
                v(x, y, height),
            ]
        } else {
            [
                v(x, y + len, 0.0),
                v(x, y, 0.0),
                v(x, y, height),
                v(x, y + len, height),
            ]
        };
        // left façades run along -y as seen from the street: flip u so the text reads
        let (u0, u1) = if side > 0.0 { (0.0, 1.0) } else { (1.0, 0.0) };
        m.quad(q, tex, [u0, 0.0], [u1, 1.0]);
        s.add_static(
            &format!("building {k}"),
            None,
            m,
            pose_xy(0.0, 0.0, 0.0, 0.0),
        );
        y += len;
        k += 1;
    }
    if side > 0.0 {
        // the end of the street: a building across it
        let tex = s.add_texture(facade(rng, 2.0 * FACADE + 4.0, 14.0).into_texture());
        let y = STREET_Y[1];
        let (x0, x1) = (-FACADE - 2.0, FACADE + 2.0);
        let v = P3::new;
        let mut m = Mesh::default();
        m.quad(
            [v(x0, y, 0.0), v(x1, y, 0.0), v(x1, y, 14.0), v(x0, y, 14.0)],
            tex,
            [0.0, 0.0],
            [1.0, 1.0],
        );
        s.add_static("end of the street", None, m, pose_xy(0.0, 0.0, 0.0, 0.0));
    }
}

/// Lamp posts and sign posts at the kerbs.
fn street_furniture(s: &mut Scene, rng: &mut Pcg64Mcg) {
    let metal = s.paint(Style::Plain([0.22, 0.24, 0.25]), 16, 16, rng);
    let sign = s.paint(Style::Poster, 128, 128, rng);
    for side in [-1.0f64, 1.0] {
        let mut y = STREET_Y[0] + rng.random_range(0.0..10.0);
        while y < STREET_Y[1] {
            let x = side * (KERB + 0.5);
            let mut m = Mesh::prism(8, [0.07, 0.07], [0.09, 0.09], 5.0, metal)
                .translated(P3::new(0.0, 0.0, 5.0));
            m.extend(Mesh::cuboid(
                P3::new(-0.25, -0.15, 4.9),
                P3::new(0.25, 0.15, 5.05),
                metal,
            ));
            if rng.random_bool(0.4) {
                m.extend(Mesh::cuboid(
                    P3::new(-0.3, -0.12, 2.2),
                    P3::new(0.3, -0.1, 2.8),
                    sign,
                ));
            }
            s.add_static("post", None, m, pose_xy(x, y, 0.12, 0.0));
            y += rng.random_range(14.0..22.0);
        }
    }
}

/// A car 4.2-4.7 m long, its front towards +y, standing on z = 0: body, cabin with dark
/// glass, wheels, lights and plates.
fn car_mesh(s: &mut Scene, rng: &mut Pcg64Mcg) -> Mesh {
    let colours = [
        [0.75, 0.75, 0.76],
        [0.1, 0.1, 0.11],
        [0.85, 0.85, 0.84],
        [0.55, 0.1, 0.1],
        [0.15, 0.25, 0.45],
        [0.4, 0.42, 0.45],
    ];
    let colour = colours[rng.random_range(0..colours.len())];
    let body = s.paint(Style::Plain(colour), 64, 64, rng);
    let glass = s.paint(Style::Plain([0.08, 0.09, 0.11]), 32, 32, rng);
    let rubber = s.paint(Style::Plain([0.05, 0.05, 0.05]), 16, 16, rng);
    let white = s.paint(Style::Plain([0.9, 0.9, 0.85]), 16, 16, rng);
    let red = s.paint(Style::Plain([0.7, 0.05, 0.05]), 16, 16, rng);
    let plate = s.paint(Style::Poster, 64, 16, rng);
    let (l, w) = (rng.random_range(4.2..4.7), rng.random_range(1.75..1.85));
    let (hl, hw) = (l / 2.0, w / 2.0);
    let v = P3::new;
    let mut m = Mesh::cuboid(v(-hw, -hl, 0.3), v(hw, hl, 0.95), body);
    // the cabin, set back, with its glass a little proud of it on every side
    let (c0, c1) = (-hl + 0.9, hl - 1.3);
    m.extend(Mesh::cuboid(
        v(-hw + 0.1, c0, 0.95),
        v(hw - 0.1, c1, 1.45),
        body,
    ));
    m.extend(Mesh::cuboid(
        v(-hw + 0.08, c0 + 0.1, 1.0),
        v(hw - 0.08, c1 - 0.1, 1.4),
        glass,
    ));
    m.extend(Mesh::cuboid(
        v(-hw + 0.2, c0 - 0.02, 1.0),
        v(hw - 0.2, c1 + 0.02, 1.4),
        glass,
    ));
    for (x, y) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let (cx, cy) = (x * (hw - 0.12), y * (hl - 0.8));
        m.extend(Mesh::cuboid(
            v(cx - 0.13, cy - 0.33, 0.0),
            v(cx + 0.13, cy + 0.33, 0.62),
            rubber,
        ));
    }
    for x in [-1.0, 1.0] {
        let cx = x * (hw - 0.25);
        m.extend(Mesh::cuboid(
            v(cx - 0.18, hl, 0.7),
            v(cx + 0.18, hl + 0.02, 0.82),
            white,
        ));
        m.extend(Mesh::cuboid(
            v(cx - 0.18, -hl - 0.02, 0.72),
            v(cx + 0.18, -hl, 0.85),
            red,
        ));
    }
    for y in [-hl - 0.03, hl] {
        m.extend(Mesh::cuboid(
            v(-0.26, y, 0.4),
            v(0.26, y + 0.03, 0.52),
            plate,
        ));
    }
    m
}

/// Cars parked along one side's parking lane, about half the bays taken.
fn parked_cars(s: &mut Scene, rng: &mut Pcg64Mcg, side: f64) {
    let x = side * (LANE + (KERB - LANE) / 2.0);
    let mut y = STREET_Y[0] + rng.random_range(0.0..6.0);
    let mut k = 0;
    while y < STREET_Y[1] - 5.0 {
        if rng.random_bool(0.55) {
            let mesh = car_mesh(s, rng);
            // left-side cars face the other way
            let yaw = if side > 0.0 { 0.0 } else { PI };
            let yaw = yaw + rng.random_range(-0.03..0.03);
            s.add_static(
                &format!("parked car {k}"),
                Some(CAR),
                mesh,
                pose_xy(x, y, 0.0, yaw),
            );
            k += 1;
        }
        y += rng.random_range(5.5..7.0);
    }
}

/// The moving cars: one ahead in the camera's lane at about its speed (it moves along the
/// epipolar lines), two oncoming in the other lane.
fn traffic(s: &mut Scene, rng: &mut Pcg64Mcg, speed: f64) {
    // Ahead by 11-16 m, closing or opening the gap by at most 5 m over 10 s (never closer
    // than 6 m, as a driver keeps).
    let gap: f64 = rng.random_range(11.0..16.0);
    let closing = rng.random_range(-0.5..((gap - 6.0) / 10.0).min(0.5));
    let lead = car_mesh(s, rng);
    s.add(
        "car ahead",
        Some(CAR),
        vec![crate::scene::Part {
            name: "body",
            mesh: lead,
        }],
        Motion::Driving {
            start: [LANE / 2.0, gap],
            velocity: speed - closing,
        },
    );
    let mut y = rng.random_range(45.0..60.0);
    for k in 0..2 {
        let mesh = car_mesh(s, rng);
        s.add(
            &format!("oncoming car {k}"),
            Some(CAR),
            vec![crate::scene::Part { name: "body", mesh }],
            Motion::Driving {
                start: [-LANE / 2.0, y],
                velocity: -rng.random_range(7.0..10.0),
            },
        );
        y += rng.random_range(25.0..45.0);
    }
}

/// A pedestrian walking along the right-hand pavement, ahead of the camera.
fn pedestrian(s: &mut Scene, rng: &mut Pcg64Mcg, photos: &Photos) {
    let x = KERB + rng.random_range(1.0..2.0);
    let y0 = rng.random_range(20.0..35.0);
    let route = Route {
        points: vec![[x, y0], [x, y0 + 30.0]],
        dwell: vec![0.0, 0.0],
        speed: rng.random_range(1.1..1.5),
        offset: 0.0,
    };
    if let Some(p) = photos.people.first() {
        crate::presets::add_cutout_walker(s, p, "pedestrian", 1.7, route);
        return;
    }
    let o = crate::presets::random_outfit(s, rng);
    s.add(
        "pedestrian",
        Some(coco::PERSON),
        person_parts(&o),
        Motion::Walker {
            route,
            carry_until: 0.0,
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn the_camera_drives_forward_in_its_lane_and_the_car_ahead_moves_with_it() {
        for seed in 0..5 {
            let mut rng = Pcg64Mcg::seed_from_u64(seed);
            let (scene, cam) = build(&mut rng, &Photos::default());
            let (a, b) = (cam.pose(0.0), cam.pose(10.0));
            let d = b.translation.vector - a.translation.vector;
            assert!(d.y > 45.0 && d.y < 75.0, "seed {seed}: drove {} m", d.y);
            for k in 0..300 {
                let p = cam.pose(k as f64 / 30.0).translation.vector;
                assert!((p.x - LANE / 2.0).abs() < 0.3, "seed {seed}: x {}", p.x);
                assert!((p.z - CAMERA_HEIGHT).abs() < 0.05);
                // looking along the street, slightly down
                let fwd = cam.pose(k as f64 / 30.0).rotation * P3::z();
                assert!(fwd.y > 0.99 && fwd.z < 0.0, "seed {seed}: forward {fwd:?}");
            }
            let ahead = scene
                .objects
                .iter()
                .find(|o| o.name == "car ahead")
                .expect("a car ahead");
            assert_eq!(ahead.class_id, Some(CAR));
            let mut poses = Vec::new();
            ahead.motion.part_poses(10.0, &P3::zeros(), 1, &mut poses);
            let y1 = poses[0].translation.vector.y;
            let gap = y1 - b.translation.vector.y;
            assert!(
                gap > 5.0 && gap < 22.0,
                "seed {seed}: {gap} m ahead at 10 s"
            );
            let parked = scene
                .objects
                .iter()
                .filter(|o| o.name.starts_with("parked car"))
                .count();
            assert!(parked >= 20, "seed {seed}: {parked} parked cars");
        }
    }
}
