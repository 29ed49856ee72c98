//! The furnished room, the presets (which people and objects move, how the camera moves), and
//! camera paths modelled on the TUM RGB-D dynamic sequences.

use crate::mesh::{Mesh, P3};
use crate::scene::{
    Motion, Outfit, Part, Route, Scene, billboard_mesh, chair_mesh, coco, desk_mesh, laptop_mesh,
    monitor_mesh, person_parts, shelf_mesh,
};
use crate::texture::{Style, Texture, random_colour};
use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::Rng;
use rand_pcg::Pcg64Mcg;
use std::f64::consts::{PI, TAU};
use stillpoint_geometry::Se3;

/// A scene preset, named after the TUM sequence it imitates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    /// TUM fr3/walking_xyz: two people walk loops in front of the desks, the camera
    /// translates along x, y, z.
    WalkingXyz,
    /// TUM fr3/walking_static: the walkers, a nearly still camera.
    WalkingStatic,
    /// TUM fr3/walking_halfsphere: the walkers, the camera on an arc of a sphere.
    WalkingHalfsphere,
    /// TUM fr3/walking_rpy: the walkers, the camera rotating in place (roll, pitch, yaw).
    WalkingRpy,
    /// TUM fr3/sitting_xyz: two people seated at the desk, the camera translating.
    SittingXyz,
    /// TUM fr3/sitting_static: the seated people, a nearly still camera.
    SittingStatic,
    /// TUM fr3/sitting_halfsphere: the seated people, the camera on an arc of a sphere.
    SittingHalfsphere,
    /// Five walkers.
    Crowd,
    /// A walker carries a box to the desk and puts it down; a seated person lifts a book; a
    /// balloon drifts.
    PlacingBox,
    /// The camera follows a walker.
    PersonTracking,
    /// Nothing moves but the camera (the control).
    Static,
    /// The camera walks a circle of 1 m radius round the room looking outwards, back to its start
    /// after 20 s and on: a revisit far from the recent keyframes, for loop closing (nothing
    /// else moves).
    Loop,
    /// A low-texture living room (plain walls and floor, a few sparse items), a hand-held camera,
    /// and one richly textured person who walks across the view close to the camera (0.8-2.5
    /// m), stops, turns and crosses back: in view in ~1/3-1/2 of the frames, 20-50 % of the
    /// image at times. Kinect-like noise by default.
    LivingCross,
    /// The living room with the person close in front of the camera for most of the sequence
    /// (walking, stopping, turning, crossing the image; often 30-50 % of the image): the
    /// "dominant textured mover".
    LivingClose,
    /// The living room with a fast-turning hand-held camera (yaw up to ~50 deg/s) while the person
    /// crosses once (in view ~1/4 of the frames).
    LivingTurn,
    /// The living room and hand-held camera with nobody in it (the control).
    LivingEmpty,
    /// A camera on a car driving down a town street at 5-7 m/s, past parked cars, behind a car
    /// in its lane, meeting two oncoming cars, a pedestrian on the pavement (built by
    /// [`crate::street::build`]; best seen monocular, as KITTI is).
    Street,
}

impl Preset {
    /// Every preset, in the order `synth --contact-sheet --preset all` shows them.
    pub const ALL: [Preset; 17] = [
        Preset::WalkingXyz,
        Preset::WalkingStatic,
        Preset::WalkingHalfsphere,
        Preset::WalkingRpy,
        Preset::SittingXyz,
        Preset::SittingStatic,
        Preset::SittingHalfsphere,
        Preset::Crowd,
        Preset::PlacingBox,
        Preset::PersonTracking,
        Preset::Static,
        Preset::Loop,
        Preset::LivingCross,
        Preset::LivingClose,
        Preset::LivingTurn,
        Preset::LivingEmpty,
        Preset::Street,
    ];

    /// The preset's name on the command line (`walking_xyz`, ...).
    pub fn name(&self) -> &'static str {
        match self {
            Preset::WalkingXyz => "walking_xyz",
            Preset::WalkingStatic => "walking_static",
            Preset::WalkingHalfsphere => "walking_halfsphere",
            Preset::WalkingRpy => "walking_rpy",
            Preset::SittingXyz => "sitting_xyz",
            Preset::SittingStatic => "sitting_static",
            Preset::SittingHalfsphere => "sitting_halfsphere",
            Preset::Crowd => "crowd",
            Preset::PlacingBox => "placing_box",
            Preset::PersonTracking => "person_tracking",
            Preset::Static => "static",
            Preset::Loop => "loop",
            Preset::LivingCross => "living_cross",
            Preset::LivingClose => "living_close",
            Preset::LivingTurn => "living_turn",
            Preset::LivingEmpty => "living_empty",
            Preset::Street => "street",
        }
    }

    /// The living-room presets (their own room, hand-held camera, Kinect noise by default).
    pub fn is_living(&self) -> bool {
        matches!(
            self,
            Preset::LivingCross | Preset::LivingClose | Preset::LivingTurn | Preset::LivingEmpty
        )
    }

    /// The sensor noise a sequence of this preset gets unless told otherwise: Kinect-like for
    /// the living-room presets (they imitate real RGB-D footage), none for the others.
    pub fn default_noise(&self) -> crate::Noise {
        if self.is_living() {
            crate::Noise::Kinect(crate::KinectNoise::default())
        } else {
            crate::Noise::None
        }
    }

    /// Parse a preset name (as [`Preset::name`] gives it).
    pub fn from_name(s: &str) -> Option<Preset> {
        Preset::ALL.into_iter().find(|p| p.name() == s)
    }
}

/// How the camera moves. All paths are smooth in time.
#[derive(Clone, Debug)]
pub enum CameraPath {
    /// Translation around `base` (sinusoids per axis), looking along `base -> target` always
    /// (TUM "xyz"; with tiny amplitudes, "static").
    Xyz {
        /// Where the camera oscillates around (world, metres).
        base: P3,
        /// What it looks at.
        target: P3,
        /// Amplitude of the oscillation along x, y, z (metres).
        amp: P3,
        /// Period of the oscillation along x, y, z (seconds).
        period: P3,
    },
    /// Rotation about the camera centre: yaw, pitch, roll amplitudes (rad) and periods (TUM "rpy").
    Rpy {
        /// The camera's centre (world, metres).
        base: P3,
        /// What it looks at when the angles are zero.
        target: P3,
        /// Yaw, pitch and roll amplitudes (radians).
        amp: P3,
        /// Yaw, pitch and roll periods (seconds).
        period: P3,
    },
    /// An arc on a sphere around `centre`, looking at it (TUM "halfsphere").
    Halfsphere {
        /// The point looked at, centre of the sphere (world, metres).
        centre: P3,
        /// Radius of the sphere (metres).
        radius: f64,
        /// Azimuth amplitude around the -y direction (radians).
        azimuth_amp: f64,
        /// Azimuth period (seconds).
        azimuth_period: f64,
        /// Mean elevation above the horizontal (radians).
        elevation: f64,
        /// Elevation amplitude (radians).
        elevation_amp: f64,
        /// Elevation period (seconds).
        elevation_period: f64,
    },
    /// Follow a walker from behind the walker's line, at a fixed height.
    Follow {
        /// The walker's route.
        route: Route,
        /// The camera's fixed y (world, metres); its x follows the walker's at 0.7.
        y: f64,
        /// The camera's height (metres).
        height: f64,
    },
    /// Round a horizontal circle at constant speed, looking outwards (slightly down, with a
    /// gentle bob), one lap per `period` seconds from the angle `start`.
    Circle {
        /// Centre of the circle (world, metres).
        centre: P3,
        /// Radius (metres).
        radius: f64,
        /// Seconds a lap.
        period: f64,
        /// Angle of the first frame on the circle (radians, from +x).
        start: f64,
        /// How far the view points down (radians).
        pitch: f64,
    },
    /// Hand-held: looking from `base` at `target`, with smooth sums of sinusoids added to the
    /// position (world x, y, z, metres) and to the orientation (yaw, pitch, roll in the camera
    /// frame, radians, as in `Rpy`).
    Handheld {
        /// Where the camera is held (world, metres).
        base: P3,
        /// What it looks at.
        target: P3,
        /// Sinusoids added to the position along world x, y, z.
        pos: [Vec<Wave>; 3],
        /// Sinusoids added to yaw, pitch and roll.
        rot: [Vec<Wave>; 3],
    },
    /// Driving: along +y from `start` at `speed` m/s, `pitch` down, with sinusoids added to
    /// the lateral position (`sway`, along x), the height (`bounce`) and to yaw, pitch and roll
    /// (`rot`, in the camera frame, as in `Rpy`).
    Drive {
        /// Where the camera is at t = 0 (world, metres).
        start: P3,
        /// Metres a second along +y.
        speed: f64,
        /// How far the view points down (radians).
        pitch: f64,
        /// Sinusoids added to x.
        sway: Vec<Wave>,
        /// Sinusoids added to z.
        bounce: Vec<Wave>,
        /// Sinusoids added to yaw, pitch and roll.
        rot: [Vec<Wave>; 3],
    },
}

/// One sinusoid of a hand-held camera path: `amp * sin(2 pi t / period + phase)`.
#[derive(Clone, Copy, Debug)]
pub struct Wave {
    /// Amplitude (metres or radians).
    pub amp: f64,
    /// Period (seconds).
    pub period: f64,
    /// Phase (radians).
    pub phase: f64,
}

impl Wave {
    /// A sinusoid of amplitude `amp` and period `period` with a random phase.
    pub fn random(rng: &mut Pcg64Mcg, amp: f64, period: f64) -> Wave {
        Wave {
            amp,
            period,
            phase: rng.random_range(0.0..TAU),
        }
    }
}

fn waves(t: f64, w: &[Wave]) -> f64 {
    w.iter().map(|w| w.amp * wave(t, w.period, w.phase)).sum()
}

/// Camera-to-world pose at `eye` looking at `target` (camera x right, y down, z forward; world z up).
pub fn look_at(eye: P3, target: P3) -> Se3 {
    let f = (target - eye).normalize();
    let r = f.cross(&Vector3::z()).normalize();
    let d = f.cross(&r);
    let m = nalgebra::Matrix3::from_columns(&[r, d, f]);
    Isometry3::from_parts(
        Translation3::from(eye),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m)),
    )
}

fn wave(t: f64, period: f64, phase: f64) -> f64 {
    (TAU * t / period + phase).sin()
}

impl CameraPath {
    /// Camera-to-world pose at time `t`.
    pub fn pose(&self, t: f64) -> Se3 {
        match self {
            CameraPath::Xyz {
                base,
                target,
                amp,
                period,
            } => {
                let off = P3::new(
                    amp.x * wave(t, period.x, 0.3),
                    amp.y * wave(t, period.y, 1.1),
                    amp.z * wave(t, period.z, 2.0),
                );
                let mut p = look_at(*base, *target);
                p.translation.vector += off;
                p
            }
            CameraPath::Rpy {
                base,
                target,
                amp,
                period,
            } => {
                let yaw = amp.x * wave(t, period.x, 0.2);
                let pitch = amp.y * wave(t, period.y, 1.0);
                let roll = amp.z * wave(t, period.z, 2.5);
                let p = look_at(*base, *target);
                // in the camera frame: yaw about y (down), pitch about x, roll about z (forward)
                let r = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw)
                    * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), pitch)
                    * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), roll);
                Isometry3::from_parts(p.translation, p.rotation * r)
            }
            CameraPath::Halfsphere {
                centre,
                radius,
                azimuth_amp,
                azimuth_period,
                elevation,
                elevation_amp,
                elevation_period,
            } => {
                let az = azimuth_amp * wave(t, *azimuth_period, 0.0);
                let el = elevation + elevation_amp * wave(t, *elevation_period, 0.7);
                let eye =
                    centre + P3::new(az.sin() * el.cos(), -az.cos() * el.cos(), el.sin()) * *radius;
                look_at(eye, *centre)
            }
            CameraPath::Follow { route, y, height } => {
                // a moving average of the walker's position over +-1 s keeps the camera smooth
                let mut acc = [0.0, 0.0];
                let n = 21;
                for k in 0..n {
                    let s = route.state(t - 1.0 + 2.0 * k as f64 / (n - 1) as f64);
                    acc[0] += s.pos[0] / n as f64;
                    acc[1] += s.pos[1] / n as f64;
                }
                look_at(
                    P3::new(0.7 * acc[0], *y, *height),
                    P3::new(acc[0], acc[1], 1.0),
                )
            }
            CameraPath::Circle {
                centre,
                radius,
                period,
                start,
                pitch,
            } => {
                let a = start + TAU * t / period;
                let out = P3::new(a.cos(), a.sin(), 0.0);
                let bob = P3::new(0.0, 0.0, 0.05 * wave(t, 4.0, 0.0));
                let eye = centre + out * *radius + bob;
                look_at(eye, eye + out + P3::new(0.0, 0.0, -pitch.tan()))
            }
            CameraPath::Handheld {
                base,
                target,
                pos,
                rot,
            } => {
                let p = look_at(*base, *target);
                let r = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), waves(t, &rot[0]))
                    * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), waves(t, &rot[1]))
                    * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), waves(t, &rot[2]));
                let off = P3::new(waves(t, &pos[0]), waves(t, &pos[1]), waves(t, &pos[2]));
                Isometry3::from_parts(
                    Translation3::from(p.translation.vector + off),
                    p.rotation * r,
                )
            }
            CameraPath::Drive {
                start,
                speed,
                pitch,
                sway,
                bounce,
                rot,
            } => {
                let eye = start + P3::new(waves(t, sway), speed * t, waves(t, bounce));
                let p = look_at(eye, eye + P3::new(0.0, 1.0, -pitch.tan()));
                let r = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), waves(t, &rot[0]))
                    * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), waves(t, &rot[1]))
                    * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), waves(t, &rot[2]));
                Isometry3::from_parts(p.translation, p.rotation * r)
            }
        }
    }
}

/// Extra material for photo-realistic scenes (`--textures DIR`).
#[derive(Default)]
pub struct Photos {
    /// Photos hung on the walls as posters.
    pub posters: Vec<Texture>,
    /// Person cut-outs (RGBA) replacing the articulated people.
    pub people: Vec<Texture>,
}

pub(crate) fn pose_xy(x: f64, y: f64, z: f64, yaw: f64) -> Se3 {
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

/// Room bounds: x, y, z ranges (metres).
pub const ROOM: [[f64; 2]; 3] = [[-3.0, 3.0], [-2.6, 3.6], [0.0, 2.7]];

/// The inside of a box-shaped room (`[[x0, x1], [y0, y1], [z0, z1]]`): floor, ceiling and the
/// back, left, right and front walls, each one texture stretched over it.
pub(crate) fn box_room(bounds: [[f64; 2]; 3], floor: u16, ceiling: u16, walls: [u16; 4]) -> Mesh {
    let [[x0, x1], [y0, y1], [z0, z1]] = bounds;
    let v = P3::new;
    let mut room = Mesh::default();
    let quads = [
        [v(x0, y0, z0), v(x1, y0, z0), v(x1, y1, z0), v(x0, y1, z0)], // floor
        [v(x0, y0, z1), v(x1, y0, z1), v(x1, y1, z1), v(x0, y1, z1)], // ceiling
        [v(x0, y1, z0), v(x1, y1, z0), v(x1, y1, z1), v(x0, y1, z1)], // back
        [v(x0, y0, z0), v(x0, y1, z0), v(x0, y1, z1), v(x0, y0, z1)], // left
        [v(x1, y1, z0), v(x1, y0, z0), v(x1, y0, z1), v(x1, y1, z1)], // right
        [v(x1, y0, z0), v(x0, y0, z0), v(x0, y0, z1), v(x1, y0, z1)], // front
    ];
    let textures = [floor, ceiling, walls[0], walls[1], walls[2], walls[3]];
    for (q, tex) in quads.into_iter().zip(textures) {
        room.quad(q, tex, [0.0, 0.0], [1.0, 1.0]);
    }
    room
}

/// Build the furnished room (everything static), shared by every preset.
fn furnish(s: &mut Scene, rng: &mut Pcg64Mcg, photos: &Photos) {
    let [[x0, x1], [_, y1], _] = ROOM;
    let wall_colours = [
        [0.82, 0.8, 0.74],
        [0.74, 0.78, 0.8],
        [0.8, 0.76, 0.7],
        [0.78, 0.8, 0.76],
    ];
    let floor = s.paint(Style::Floor([0.45, 0.42, 0.4]), 1024, 1024, rng);
    let ceiling = s.paint(Style::Plain([0.9, 0.9, 0.88]), 256, 256, rng);
    let walls = wall_colours.map(|c| s.paint(Style::Wall(c), 1024, 512, rng));
    let room = box_room(ROOM, floor, ceiling, walls);
    let v = P3::new;
    s.add_static("room", None, room, Se3::identity());

    // photo posters on the back and side walls, a few centimetres off the wall
    for (k, tex) in photos.posters.iter().enumerate().take(4) {
        let (tw, th) = tex.size();
        let h = 0.7;
        let w = h * tw as f64 / th.max(1) as f64;
        let id = s.add_texture(tex.clone());
        let mut m = Mesh::default();
        m.quad(
            [
                v(-w / 2.0, 0.0, 0.0),
                v(w / 2.0, 0.0, 0.0),
                v(w / 2.0, 0.0, h),
                v(-w / 2.0, 0.0, h),
            ],
            id,
            [0.0, 0.0],
            [1.0, 1.0],
        );
        let pose = match k {
            0 => pose_xy(-1.5, y1 - 0.01, 1.3, 0.0),
            1 => pose_xy(1.6, y1 - 0.01, 1.4, 0.0),
            2 => pose_xy(x0 + 0.01, 1.0, 1.3, -PI / 2.0),
            _ => pose_xy(x1 - 0.01, 1.5, 1.3, PI / 2.0),
        };
        s.add_static("photo", None, m, pose);
    }

    let wood = s.paint(Style::Wood([0.75, 0.6, 0.42]), 512, 256, rng);
    let wood2 = s.paint(Style::Wood([0.85, 0.82, 0.76]), 512, 256, rng);
    let metal = s.paint(Style::Plain([0.35, 0.36, 0.38]), 64, 64, rng);
    let plastic = s.paint(Style::Plain([0.15, 0.15, 0.16]), 64, 64, rng);
    // central desk (people sit behind it) and a desk along the back wall with monitors
    s.add_static(
        "desk",
        Some(coco::DINING_TABLE),
        desk_mesh(2.2, 0.8, 0.74, wood2, metal),
        pose_xy(0.0, 2.0, 0.0, 0.0),
    );
    s.add_static(
        "desk",
        Some(coco::DINING_TABLE),
        desk_mesh(1.8, 0.7, 0.74, wood, metal),
        pose_xy(1.7, 3.2, 0.0, 0.0),
    );
    s.add_static(
        "desk",
        Some(coco::DINING_TABLE),
        desk_mesh(1.4, 0.7, 0.74, wood, metal),
        pose_xy(-2.6, 0.9, 0.0, PI / 2.0),
    );
    for (x, y, yaw) in [
        (1.25, 3.3, 0.0),
        (2.05, 3.35, -0.15),
        (-2.75, 0.9, PI / 2.0),
    ] {
        let screen = s.paint(Style::Screen, 384, 256, rng);
        s.add_static(
            "monitor",
            Some(coco::TV),
            monitor_mesh(screen, plastic),
            pose_xy(x, y, 0.74, yaw),
        );
        let keys = s.paint(Style::Plain([0.2, 0.2, 0.22]), 128, 64, rng);
        let kb = Mesh::cuboid(P3::new(-0.22, -0.07, 0.0), P3::new(0.22, 0.07, 0.025), keys);
        let fwd = P3::new(-(yaw.sin()), yaw.cos(), 0.0);
        s.add_static(
            "keyboard",
            Some(coco::KEYBOARD),
            kb,
            pose_xy(x - 0.3 * fwd.x, y - 0.3 * fwd.y, 0.74, yaw),
        );
    }
    // things on the central desk
    let lap_body = s.paint(Style::Plain([0.7, 0.7, 0.72]), 128, 64, rng);
    let lap_screen = s.paint(Style::Plain([0.55, 0.56, 0.6]), 128, 64, rng);
    s.add_static(
        "laptop",
        Some(coco::LAPTOP),
        laptop_mesh(lap_body, lap_screen),
        pose_xy(-0.5, 2.05, 0.74, PI),
    );
    let keys = s.paint(Style::Plain([0.85, 0.85, 0.85]), 128, 64, rng);
    s.add_static(
        "keyboard",
        Some(coco::KEYBOARD),
        Mesh::cuboid(P3::new(-0.22, -0.07, 0.0), P3::new(0.22, 0.07, 0.025), keys),
        pose_xy(0.55, 2.1, 0.74, 0.1),
    );
    for k in 0..3 {
        let cover = s.paint(Style::Poster, 96, 128, rng);
        let b = Mesh::cuboid(
            P3::new(-0.085, -0.12, 0.0),
            P3::new(0.085, 0.12, 0.035),
            cover,
        );
        s.add_static(
            "book",
            Some(coco::BOOK),
            b,
            pose_xy(
                0.0 + 0.02 * k as f64,
                1.85,
                0.74 + 0.035 * k as f64,
                0.3 * k as f64,
            ),
        );
    }
    let cup = s.paint(Style::Plain([0.8, 0.2, 0.15]), 64, 32, rng);
    s.add_static(
        "cup",
        Some(coco::CUP),
        Mesh::prism(10, [0.04, 0.04], [0.035, 0.035], 0.1, cup).translated(P3::new(0.0, 0.0, 0.1)),
        pose_xy(0.95, 1.75, 0.74, 0.0),
    );
    let bottle = s.paint(Style::Plain([0.3, 0.6, 0.3]), 64, 64, rng);
    s.add_static(
        "bottle",
        Some(coco::BOTTLE),
        Mesh::prism(10, [0.02, 0.02], [0.035, 0.035], 0.26, bottle)
            .translated(P3::new(0.0, 0.0, 0.26)),
        pose_xy(2.3, 3.1, 0.74, 0.0),
    );

    // shelves with books on the back wall, cartons, a cabinet and a plant
    let books = s.paint(Style::Books, 512, 256, rng);
    s.add_static(
        "shelf",
        None,
        shelf_mesh(1.6, 0.35, 1.9, wood, books),
        pose_xy(-1.6, y1 - 0.18, 0.0, 0.0),
    );
    let card = s.paint(Style::Cardboard, 384, 256, rng);
    s.add_static(
        "cartons",
        None,
        Mesh::cuboid(P3::new(-0.3, -0.25, 0.0), P3::new(0.3, 0.25, 0.45), card),
        pose_xy(-0.3, 3.25, 0.0, 0.1),
    );
    let card2 = s.paint(Style::Cardboard, 384, 256, rng);
    s.add_static(
        "cartons",
        None,
        Mesh::cuboid(P3::new(-0.25, -0.2, 0.0), P3::new(0.25, 0.2, 0.35), card2),
        pose_xy(-0.25, 3.2, 0.45, -0.2),
    );
    let cab = s.paint(Style::Wood([0.6, 0.62, 0.65]), 256, 256, rng);
    s.add_static(
        "cabinet",
        None,
        Mesh::cuboid(P3::new(-0.3, -0.25, 0.0), P3::new(0.3, 0.25, 1.05), cab),
        pose_xy(2.6, 1.6, 0.0, 0.0),
    );
    let pot = s.paint(Style::Plain([0.55, 0.3, 0.2]), 64, 64, rng);
    let leaves = s.paint(Style::Leaves, 256, 128, rng);
    let mut plant =
        Mesh::prism(10, [0.15, 0.15], [0.11, 0.11], 0.35, pot).translated(P3::new(0.0, 0.0, 0.35));
    plant.extend(
        Mesh::ellipsoid(P3::new(0.3, 0.3, 0.45), 6, 10, leaves).translated(P3::new(0.0, 0.0, 0.8)),
    );
    s.add_static(
        "plant",
        Some(coco::POTTED_PLANT),
        plant.clone(),
        pose_xy(2.4, 0.2, 0.0, 0.0),
    );
    s.add_static(
        "plant",
        Some(coco::POTTED_PLANT),
        plant,
        pose_xy(-2.5, 3.1, 0.0, 0.4),
    );
    // empty chairs; one stands in the walkers' way (partly in front of them)
    let seat = s.paint(Style::Fabric([0.25, 0.3, 0.5]), 192, 128, rng);
    s.add_static(
        "chair",
        Some(coco::CHAIR),
        chair_mesh(seat, metal),
        pose_xy(-1.25, -0.35, 0.0, 2.4),
    );
    s.add_static(
        "chair",
        Some(coco::CHAIR),
        chair_mesh(seat, metal),
        pose_xy(1.6, 2.75, 0.0, 0.2),
    );
    s.add_static(
        "chair",
        Some(coco::CHAIR),
        chair_mesh(seat, metal),
        pose_xy(-2.1, 0.9, 0.0, -PI / 2.0),
    );
}

pub(crate) fn random_outfit(s: &mut Scene, rng: &mut Pcg64Mcg) -> Outfit {
    let skins = [
        [0.87, 0.7, 0.58],
        [0.62, 0.45, 0.33],
        [0.95, 0.8, 0.7],
        [0.45, 0.3, 0.22],
    ];
    let hairs = [
        [0.2, 0.14, 0.08],
        [0.05, 0.05, 0.05],
        [0.6, 0.45, 0.25],
        [0.35, 0.3, 0.28],
    ];
    // everyday clothes: muted shirts (white, grey, navy, black, dark red, olive, light blue,
    // beige) and dark or denim trousers, as in TUM fr3
    let shirts = [
        [0.85, 0.85, 0.83],
        [0.5, 0.5, 0.52],
        [0.15, 0.2, 0.4],
        [0.12, 0.12, 0.13],
        [0.5, 0.12, 0.12],
        [0.35, 0.38, 0.22],
        [0.55, 0.68, 0.85],
        [0.75, 0.65, 0.5],
    ];
    let mut shirt = shirts[rng.random_range(0..shirts.len())];
    let tint = random_colour(rng);
    for (c, t) in shirt.iter_mut().zip(tint) {
        *c = 0.85 * *c + 0.15 * t;
    }
    let trousers = if rng.random_bool(0.5) {
        let g = rng.random_range(0.08..0.3f32);
        [g, g, g * 1.1]
    } else {
        [0.2, 0.27, 0.42]
    };
    let skin = skins[rng.random_range(0..skins.len())];
    let hair = hairs[rng.random_range(0..hairs.len())];
    s.outfit(shirt, trousers, skin, hair, rng)
}

/// Height of a billboard person standing (m); cut-outs are scaled to it keeping their aspect.
pub const BILLBOARD_HEIGHT: f64 = 1.45;

/// A photographed person cut-out `height` metres tall (aspect kept), a billboard turned to the
/// camera, walking `route`.
pub(crate) fn add_cutout_walker(
    s: &mut Scene,
    cutout: &Texture,
    name: &str,
    height: f64,
    route: Route,
) {
    let (w, h) = cutout.size();
    let id = s.add_texture(cutout.clone());
    let mesh = billboard_mesh(height * w as f64 / h as f64, height, id);
    s.add(
        name,
        Some(coco::PERSON),
        vec![Part {
            name: "cutout",
            mesh,
        }],
        Motion::Billboard {
            route: Some(route),
            fixed: [0.0, 0.0],
            bob: true,
        },
    );
}

fn add_walker(
    s: &mut Scene,
    rng: &mut Pcg64Mcg,
    photos: &Photos,
    name: &str,
    route: Route,
    carry_until: f64,
) {
    if let Some(p) = photos
        .people
        .get(s.objects.len() % photos.people.len().max(1))
    {
        add_cutout_walker(s, p, name, BILLBOARD_HEIGHT, route);
        return;
    }
    let o = random_outfit(s, rng);
    s.add(
        name,
        Some(coco::PERSON),
        person_parts(&o),
        Motion::Walker { route, carry_until },
    );
}

/// A chair at (x, y) turned by `yaw` (the sitter faces the chair's +y turned by yaw), with a
/// seated person on it.
fn add_seated(
    s: &mut Scene,
    rng: &mut Pcg64Mcg,
    photos: &Photos,
    x: f64,
    y: f64,
    yaw: f64,
    phase: f64,
) {
    let metal = s.paint(Style::Plain([0.3, 0.3, 0.32]), 64, 64, rng);
    let seat = s.paint(Style::Fabric([0.5, 0.35, 0.2]), 192, 128, rng);
    s.add_static(
        "chair",
        Some(coco::CHAIR),
        chair_mesh(seat, metal),
        pose_xy(x, y, 0.0, yaw),
    );
    if let Some(p) = photos.people.first() {
        let (w, h) = p.size();
        let id = s.add_texture(p.clone());
        let hh = 1.3;
        let mesh = billboard_mesh(hh * w as f64 / h as f64, hh, id);
        s.add(
            "seated person",
            Some(coco::PERSON),
            vec![Part {
                name: "cutout",
                mesh,
            }],
            Motion::Billboard {
                route: None,
                fixed: [x, y],
                bob: false,
            },
        );
        return;
    }
    let o = random_outfit(s, rng);
    let base = pose_xy(x, y, 0.0, yaw) * pose_xy(0.0, -0.05, 0.0, 0.0);
    s.add(
        "seated person",
        Some(coco::PERSON),
        person_parts(&o),
        Motion::Seated { base, phase },
    );
}

/// Build a preset's scene and camera path.
pub fn build(preset: Preset, rng: &mut Pcg64Mcg, photos: &Photos) -> (Scene, CameraPath) {
    if preset.is_living() {
        return crate::living::build(preset, rng, photos);
    }
    if preset == Preset::Street {
        return crate::street::build(rng, photos);
    }
    let mut s = Scene::new();
    furnish(&mut s, rng, photos);
    let eye = P3::new(0.0, -1.35, 1.35);
    let target = P3::new(0.0, 2.0, 0.85);
    let xyz = CameraPath::Xyz {
        base: eye,
        target,
        amp: P3::new(0.45, 0.2, 0.2),
        period: P3::new(14.0, 9.0, 11.0),
    };
    let still = CameraPath::Xyz {
        base: eye,
        target,
        amp: P3::new(0.005, 0.004, 0.004),
        period: P3::new(5.0, 7.0, 9.0),
    };
    let rpy = CameraPath::Rpy {
        base: eye,
        target,
        amp: P3::new(30f64.to_radians(), 12f64.to_radians(), 18f64.to_radians()),
        period: P3::new(10.0, 7.0, 12.0),
    };
    let half = |centre: P3| CameraPath::Halfsphere {
        centre,
        radius: 2.6,
        azimuth_amp: 35f64.to_radians(),
        azimuth_period: 24.0,
        elevation: 12f64.to_radians(),
        elevation_amp: 8f64.to_radians(),
        elevation_period: 15.0,
    };
    // fr3/sitting_*: the camera stands across the desk from the two sitters, about 1.6-2.2 m
    // from them, so they fill ~20-35 % of the image while the wall, shelf and monitors behind
    // them stay in view for tracking
    let sit_eye = P3::new(0.0, 1.25, 1.3);
    let sit_target = P3::new(0.0, 2.65, 0.9);
    let sit_xyz = CameraPath::Xyz {
        base: sit_eye,
        target: sit_target,
        amp: P3::new(0.3, 0.1, 0.1),
        period: P3::new(14.0, 9.0, 11.0),
    };
    let sit_still = CameraPath::Xyz {
        base: sit_eye,
        target: sit_target,
        amp: P3::new(0.005, 0.004, 0.004),
        period: P3::new(5.0, 7.0, 9.0),
    };
    let sit_half = CameraPath::Halfsphere {
        centre: P3::new(0.0, 2.6, 0.85),
        radius: 1.5,
        azimuth_amp: 30f64.to_radians(),
        azimuth_period: 24.0,
        elevation: 14f64.to_radians(),
        elevation_amp: 6f64.to_radians(),
        elevation_period: 15.0,
    };
    // two walkers crossing in front of the camera at 1-2.2 m, as in fr3/walking_* (people cover
    // ~22 % of the image on average in walking_xyz, 23 % in walking_static)
    let walkers = |s: &mut Scene, rng: &mut Pcg64Mcg| {
        add_walker(
            s,
            rng,
            photos,
            "walker",
            Route::ellipse([-0.05, 0.05], [0.7, 0.35], 0.8, 0.0, false),
            0.0,
        );
        add_walker(
            s,
            rng,
            photos,
            "walker",
            Route::ellipse([0.1, 0.5], [0.75, 0.3], 0.7, 2.5, true),
            0.0,
        );
    };
    let sitters = |s: &mut Scene, rng: &mut Pcg64Mcg| {
        add_seated(s, rng, photos, -0.5, 2.65, PI - 0.35, 0.0);
        add_seated(s, rng, photos, 0.55, 2.6, PI + 0.45, 2.0);
    };
    let cam = match preset {
        Preset::WalkingXyz => {
            walkers(&mut s, rng);
            xyz
        }
        Preset::WalkingStatic => {
            walkers(&mut s, rng);
            still
        }
        Preset::WalkingHalfsphere => {
            walkers(&mut s, rng);
            half(P3::new(0.0, 1.3, 0.9))
        }
        Preset::WalkingRpy => {
            walkers(&mut s, rng);
            rpy
        }
        Preset::SittingXyz => {
            sitters(&mut s, rng);
            sit_xyz
        }
        Preset::SittingStatic => {
            sitters(&mut s, rng);
            sit_still
        }
        Preset::SittingHalfsphere => {
            sitters(&mut s, rng);
            sit_half
        }
        Preset::Crowd => {
            let routes = [
                Route::ellipse([-0.1, 0.25], [1.1, 0.4], 0.8, 0.0, false),
                Route::ellipse([0.2, 0.75], [1.2, 0.35], 0.7, 2.5, true),
                Route::ellipse([0.0, 0.8], [1.7, 0.6], 1.0, 4.5, false),
                Route::ellipse([-0.4, 1.2], [0.9, 0.3], 0.7, 1.0, true),
                Route::ellipse([0.6, 0.4], [0.8, 0.4], 0.85, 3.0, true),
            ];
            for r in routes {
                add_walker(&mut s, rng, photos, "walker", r, 0.0);
            }
            xyz
        }
        Preset::PlacingBox => {
            // carry a box from the left to the central desk, put it down, walk on
            let route = Route {
                points: vec![[-2.2, 0.6], [0.3, 1.2], [1.4, 0.5], [-0.5, 0.2]],
                dwell: vec![0.0, 1.5, 0.0, 0.0],
                speed: 0.8,
                offset: 0.0,
            };
            let place_at = 1;
            let lower = 1.0;
            let arrive = route.arrival_time(place_at);
            let card = s.paint(Style::Cardboard, 256, 192, rng);
            let bx = Mesh::cuboid(P3::new(-0.2, -0.15, -0.15), P3::new(0.2, 0.15, 0.15), card);
            let place = pose_xy(0.3, 1.8, 0.74 + 0.15, 0.0);
            s.add(
                "box",
                Some(coco::SUITCASE),
                vec![Part {
                    name: "body",
                    mesh: bx,
                }],
                Motion::Carried {
                    route: route.clone(),
                    place_at,
                    lower,
                    place,
                },
            );
            add_walker(&mut s, rng, photos, "walker", route, arrive + lower);
            add_seated(&mut s, rng, photos, -0.55, 2.75, PI - 0.35, 1.0);
            let cover = s.paint(Style::Poster, 96, 128, rng);
            let book = Mesh::cuboid(
                P3::new(-0.085, -0.12, 0.0),
                P3::new(0.085, 0.12, 0.03),
                cover,
            );
            s.add(
                "book",
                Some(coco::BOOK),
                vec![Part {
                    name: "body",
                    mesh: book,
                }],
                Motion::Lifted {
                    base: pose_xy(-0.45, 2.2, 0.74, 0.2),
                    lift: 0.25,
                    period: 5.0,
                    duration: 2.5,
                    phase: 1.0,
                },
            );
            let skin = s.paint(Style::Plain([0.85, 0.15, 0.2]), 128, 64, rng);
            let mut balloon = Mesh::ellipsoid(P3::new(0.14, 0.14, 0.17), 8, 12, skin);
            balloon.extend(
                Mesh::prism(
                    4,
                    [0.003, 0.003],
                    [0.003, 0.003],
                    0.6,
                    metal_tex(&mut s, rng),
                )
                .translated(P3::new(0.0, 0.0, -0.17)),
            );
            s.add(
                "balloon",
                Some(coco::SPORTS_BALL),
                vec![Part {
                    name: "body",
                    mesh: balloon,
                }],
                Motion::Floating {
                    base: P3::new(1.0, 1.4, 1.5),
                    amp: P3::new(0.3, 0.15, 0.1),
                    period: P3::new(9.0, 7.0, 5.0),
                },
            );
            xyz
        }
        Preset::PersonTracking => {
            let route = Route::ellipse([0.0, 0.9], [1.8, 0.5], 0.8, 0.0, false);
            add_walker(&mut s, rng, photos, "walker", route.clone(), 0.0);
            CameraPath::Follow {
                route,
                y: -1.3,
                height: 1.4,
            }
        }
        Preset::Static => xyz,
        // Starts facing the back wall (shelf, desks, monitors); a lap is 6.3 m in 20 s.
        Preset::Loop => CameraPath::Circle {
            centre: P3::new(0.0, 0.4, 1.3),
            radius: 1.0,
            period: 20.0,
            start: PI / 2.0,
            pitch: 10f64.to_radians(),
        },
        Preset::LivingCross
        | Preset::LivingClose
        | Preset::LivingTurn
        | Preset::LivingEmpty
        | Preset::Street => {
            unreachable!("the living-room and street presets are built by their own modules")
        }
    };
    (s, cam)
}

fn metal_tex(s: &mut Scene, rng: &mut Pcg64Mcg) -> u16 {
    s.paint(Style::Plain([0.9, 0.9, 0.9]), 8, 8, rng)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_points_the_optical_axis_at_the_target() {
        let p = look_at(P3::new(1.0, -1.0, 1.5), P3::new(0.0, 2.0, 0.5));
        let t_c = p.inverse().transform_point(&P3::new(0.0, 2.0, 0.5).into());
        assert!(t_c.x.abs() < 1e-12 && t_c.y.abs() < 1e-12 && t_c.z > 0.0);
        // world up is image up (camera -y)
        let up_c = p.inverse().rotation * P3::z();
        assert!(up_c.y < 0.0);
        assert!((p.rotation.to_rotation_matrix().matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn camera_paths_are_smooth_and_tum_like() {
        let mut rng = rand::SeedableRng::seed_from_u64(1);
        for preset in [
            Preset::WalkingXyz,
            Preset::WalkingRpy,
            Preset::WalkingHalfsphere,
            Preset::PersonTracking,
            Preset::Loop,
        ] {
            let (_, cam) = build_cameras_only(preset, &mut rng);
            let mut max_v: f64 = 0.0;
            for k in 0..900 {
                let (a, b) = (cam.pose(k as f64 / 30.0), cam.pose((k + 1) as f64 / 30.0));
                max_v = max_v.max((b.translation.vector - a.translation.vector).norm() * 30.0);
                let p = a.translation.vector;
                assert!(
                    p.x > ROOM[0][0] && p.x < ROOM[0][1] && p.y > ROOM[1][0] && p.y < ROOM[1][1]
                );
            }
            assert!(max_v < 0.7, "{preset:?} camera speed {max_v} m/s");
        }
    }

    fn build_cameras_only(p: Preset, rng: &mut Pcg64Mcg) -> (usize, CameraPath) {
        let (s, c) = build(p, rng, &Photos::default());
        (s.objects.len(), c)
    }
}
