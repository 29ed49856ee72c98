//! Scene content: objects made of rigid parts, and how each part moves in time (walking and
//! seated people, carried, lifted and floating objects, billboards). World frame: x right, y
//! into the room, z up, metres; time in seconds from the first frame.

use crate::mesh::{Mesh, P3};
use crate::texture::{Style, Texture, procedural};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand_pcg::Pcg64Mcg;
use std::f64::consts::{FRAC_PI_2, PI, TAU};
use stillpoint_geometry::Se3;

/// COCO class ids used by the generator.
pub mod coco {
    /// A person.
    pub const PERSON: u16 = 0;
    /// The carried cardboard box: COCO has no "box"; suitcase is the nearest container class.
    pub const SUITCASE: u16 = 28;
    /// The balloon: COCO has no balloon; sports ball is the nearest class.
    pub const SPORTS_BALL: u16 = 32;
    /// A bottle.
    pub const BOTTLE: u16 = 39;
    /// A cup.
    pub const CUP: u16 = 41;
    /// A chair.
    pub const CHAIR: u16 = 56;
    /// A couch (the living room's sofa).
    pub const COUCH: u16 = 57;
    /// A potted plant.
    pub const POTTED_PLANT: u16 = 58;
    /// Desks: COCO's "dining table".
    pub const DINING_TABLE: u16 = 60;
    /// A TV (the monitors on the desks).
    pub const TV: u16 = 62;
    /// A laptop.
    pub const LAPTOP: u16 = 63;
    /// A keyboard.
    pub const KEYBOARD: u16 = 66;
    /// A book.
    pub const BOOK: u16 = 73;
}

/// One rigid piece of an object.
#[derive(Clone, Debug)]
pub struct Part {
    /// The part's name (`PERSON_PARTS` for people).
    pub name: &'static str,
    /// Its triangles, in its own frame.
    pub mesh: Mesh,
}

/// Something in the scene with an identity: the room, a desk, a person.
#[derive(Clone, Debug)]
pub struct Object {
    /// Its name (`walker`, `desk`, ...).
    pub name: String,
    /// COCO class; `None` for things that get no box (walls, shelves, static cartons).
    pub class_id: Option<u16>,
    /// Its rigid parts.
    pub parts: Vec<Part>,
    /// How the parts move in time.
    pub motion: Motion,
}

/// A person walking a closed route of waypoints at constant speed, standing `dwell` seconds
/// at each waypoint (turning on the spot there).
#[derive(Clone, Debug)]
pub struct Route {
    /// Waypoints on the floor (x, y, metres); the route closes back to the first.
    pub points: Vec<[f64; 2]>,
    /// Seconds standing at each waypoint.
    pub dwell: Vec<f64>,
    /// Walking speed, metres a second.
    pub speed: f64,
    /// Seconds added to the clock, so walkers on one route are spread out.
    pub offset: f64,
}

/// Where a walker is at one instant.
#[derive(Clone, Copy, Debug)]
pub struct RouteState {
    /// Position on the floor (x, y, metres).
    pub pos: [f64; 2],
    /// Angle about z of the body's forward (+y) axis.
    pub heading: f64,
    /// Distance walked since t = -offset (drives the gait).
    pub walked: f64,
    /// Whether the walker is walking (not standing at a waypoint).
    pub walking: bool,
}

fn heading_of(d: [f64; 2]) -> f64 {
    (-d[0]).atan2(d[1])
}

fn angle_lerp(a: f64, b: f64, t: f64) -> f64 {
    let mut d = (b - a) % TAU;
    if d > PI {
        d -= TAU;
    } else if d < -PI {
        d += TAU;
    }
    a + d * t
}

fn smoothstep(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl Route {
    /// An ellipse as a 48-gon, walked anticlockwise (or clockwise when `clockwise`).
    pub fn ellipse(
        centre: [f64; 2],
        radii: [f64; 2],
        speed: f64,
        offset: f64,
        clockwise: bool,
    ) -> Route {
        let n = 48;
        let points = (0..n)
            .map(|k| {
                let a = TAU * k as f64 / n as f64 * if clockwise { -1.0 } else { 1.0 };
                [
                    centre[0] + radii[0] * a.cos(),
                    centre[1] + radii[1] * a.sin(),
                ]
            })
            .collect();
        Route {
            points,
            dwell: vec![0.0; n],
            speed,
            offset,
        }
    }

    fn seg(&self, i: usize) -> ([f64; 2], [f64; 2], f64) {
        let a = self.points[i];
        let b = self.points[(i + 1) % self.points.len()];
        let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
        (a, b, len)
    }

    /// Length and duration of one lap.
    fn lap(&self) -> (f64, f64) {
        let n = self.points.len();
        let len: f64 = (0..n).map(|i| self.seg(i).2).sum();
        (len, len / self.speed + self.dwell.iter().sum::<f64>())
    }

    /// The time (within a lap, from the lap's start) at which the walker reaches waypoint `k`.
    pub fn arrival_time(&self, k: usize) -> f64 {
        let mut t = 0.0;
        for i in 0..k {
            t += self.dwell[i] + self.seg(i).2 / self.speed;
        }
        t - self.offset
    }

    /// Where the walker is at time `t` (seconds).
    pub fn state(&self, t: f64) -> RouteState {
        let n = self.points.len();
        let (lap_len, lap_time) = self.lap();
        let tt = t + self.offset;
        let laps = (tt / lap_time).floor();
        let mut r = tt - laps * lap_time;
        let mut walked = laps * lap_len;
        for i in 0..n {
            let (a, b, len) = self.seg(i);
            let prev = self.seg((i + n - 1) % n);
            let h_in = heading_of([prev.1[0] - prev.0[0], prev.1[1] - prev.0[1]]);
            let h_out = heading_of([b[0] - a[0], b[1] - a[1]]);
            if r < self.dwell[i] {
                return RouteState {
                    pos: a,
                    heading: angle_lerp(h_in, h_out, smoothstep(r / self.dwell[i])),
                    walked,
                    walking: false,
                };
            }
            r -= self.dwell[i];
            let dt = len / self.speed;
            if r < dt || i == n - 1 {
                let f = (r / dt).min(1.0);
                // turn smoothly over the first and last 15 cm of a segment when not dwelling
                let next = self.seg((i + 1) % n);
                let h_next = heading_of([next.1[0] - next.0[0], next.1[1] - next.0[1]]);
                let d_in = f * len;
                let d_out = (1.0 - f) * len;
                let mut heading = h_out;
                if self.dwell[i] == 0.0 && d_in < 0.15 {
                    heading = angle_lerp(h_in, h_out, 0.5 + 0.5 * d_in / 0.15);
                } else if self.dwell[(i + 1) % n] == 0.0 && d_out < 0.15 {
                    heading = angle_lerp(h_out, h_next, 0.5 - 0.5 * d_out / 0.15);
                }
                return RouteState {
                    pos: [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f],
                    heading,
                    walked: walked + d_in,
                    walking: true,
                };
            }
            r -= dt;
            walked += len;
        }
        unreachable!("the last segment always returns")
    }
}

/// How an object's parts move.
#[derive(Clone, Debug)]
pub enum Motion {
    /// All parts fixed at one pose.
    Static(Se3),
    /// An articulated person (parts in [`PERSON_PARTS`] order) walking a route; `carry_until`
    /// holds the arms forward (carrying) until that time.
    Walker {
        /// The route walked.
        route: Route,
        /// Time until which the arms hold something (seconds).
        carry_until: f64,
    },
    /// An articulated person seated on a chair at `base` (pelvis above the seat): legs and torso
    /// still, head and arms moving in bursts (`phase` shifts the bursts).
    Seated {
        /// The pelvis's pose above the seat.
        base: Se3,
        /// Shift of the head and arm bursts (seconds).
        phase: f64,
    },
    /// Carried by a walker in front of the hands until `route`'s arrival at waypoint
    /// `place_at`, lowered onto `place` over `lower` seconds, then still.
    Carried {
        /// The carrier's route.
        route: Route,
        /// The waypoint where the object is put down.
        place_at: usize,
        /// Seconds spent lowering it.
        lower: f64,
        /// Where it rests after.
        place: Se3,
    },
    /// Lifted from `base` by `lift` metres and tilted, once every `period` seconds for
    /// `duration` seconds, resting in between.
    Lifted {
        /// The resting pose.
        base: Se3,
        /// How high it is lifted (metres).
        lift: f64,
        /// Seconds between lifts.
        period: f64,
        /// Seconds a lift lasts.
        duration: f64,
        /// Shift of the lifts in time (seconds).
        phase: f64,
    },
    /// Drifting around `base` (a balloon).
    Floating {
        /// The centre of the drift (world, metres).
        base: P3,
        /// Drift amplitude along x, y, z (metres).
        amp: P3,
        /// Drift period along x, y, z (seconds).
        period: P3,
    },
    /// A vehicle driving straight along y at a constant `velocity` (m/s; negative drives
    /// towards -y, turned round), from `start` (x, y) at t = 0.
    Driving {
        /// Where it is at t = 0 (x, y, metres).
        start: [f64; 2],
        /// Metres a second along +y.
        velocity: f64,
    },
    /// A flat cut-out that stands at a route's position (or `fixed`) and turns to face the
    /// camera.
    Billboard {
        /// The route it stands on, or `None` to stand at `fixed`.
        route: Option<Route>,
        /// Where it stands without a route (x, y, metres).
        fixed: [f64; 2],
        /// It bobs up and down while its route walks (a walking cut-out person).
        bob: bool,
    },
}

/// Names of the parts of an articulated person, in order.
pub const PERSON_PARTS: [&str; 10] = [
    "torso",
    "head",
    "left_upper_arm",
    "left_forearm",
    "right_upper_arm",
    "right_forearm",
    "left_thigh",
    "left_shin",
    "right_thigh",
    "right_shin",
];

fn iso(t: P3, r: UnitQuaternion<f64>) -> Se3 {
    Isometry3::from_parts(Translation3::from(t), r)
}

fn rx(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), a)
}
fn ry(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::y_axis(), a)
}
fn rz(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a)
}

/// Joint angles of a person (radians; limb "swing" turns about the body's x axis, positive
/// forward).
#[derive(Clone, Copy, Debug, Default)]
struct Pose {
    pelvis: f64,
    torso_pitch: f64,
    torso_yaw: f64,
    head_yaw: f64,
    head_pitch: f64,
    shoulder: [f64; 2],
    shoulder_out: [f64; 2],
    elbow: [f64; 2],
    hip: [f64; 2],
    knee: [f64; 2],
}

/// World poses of the ten person parts for a body frame and joint angles.
fn person_part_poses(body: &Se3, p: &Pose, out: &mut Vec<Se3>) {
    let torso = body
        * iso(
            P3::new(0.0, 0.0, p.pelvis),
            rz(p.torso_yaw) * rx(-p.torso_pitch),
        );
    let head = torso * iso(P3::new(0.0, 0.0, 0.58), rz(p.head_yaw) * rx(-p.head_pitch));
    out.push(torso);
    out.push(head);
    for (side, sx) in [(0usize, -1.0f64), (1, 1.0)] {
        let upper = torso
            * iso(
                P3::new(0.23 * sx, 0.0, 0.5),
                ry(-sx * p.shoulder_out[side]) * rx(p.shoulder[side]),
            );
        let fore = upper * iso(P3::new(0.0, 0.0, -0.3), rx(p.elbow[side]));
        out.push(upper);
        out.push(fore);
    }
    for (side, sx) in [(0usize, -1.0f64), (1, 1.0)] {
        let thigh = body * iso(P3::new(0.1 * sx, 0.0, p.pelvis), rx(p.hip[side]));
        let shin = thigh * iso(P3::new(0.0, 0.0, -0.45), rx(-p.knee[side]));
        out.push(thigh);
        out.push(shin);
    }
}

/// Gait: stride length (m) of one full cycle (two steps).
const STRIDE: f64 = 1.3;

fn walking_pose(state: &RouteState, carrying: bool) -> Pose {
    let ph = TAU * state.walked / STRIDE;
    let a = if state.walking { 1.0 } else { 0.0 };
    let s = ph.sin();
    let mut p = Pose {
        pelvis: 0.95 + a * 0.015 * (2.0 * ph).cos(),
        torso_pitch: 0.04 * a,
        torso_yaw: 0.06 * a * s,
        head_yaw: -0.04 * a * s,
        head_pitch: 0.05,
        shoulder: [-0.35 * a * s, 0.35 * a * s],
        shoulder_out: [0.08, 0.08],
        elbow: [0.25 + 0.2 * a * (-s).max(0.0), 0.25 + 0.2 * a * s.max(0.0)],
        hip: [0.3 * a * s, -0.3 * a * s],
        knee: [
            0.1 + a * 0.6 * (ph + FRAC_PI_2).sin().max(0.0),
            0.1 + a * 0.6 * (ph + FRAC_PI_2 + PI).sin().max(0.0),
        ],
    };
    if carrying {
        p.shoulder = [0.55, 0.55];
        p.elbow = [0.9, 0.9];
        p.shoulder_out = [0.02, 0.02];
    }
    p
}

/// The body frame of a walker on its route at `t`.
fn route_body(state: &RouteState) -> Se3 {
    iso(P3::new(state.pos[0], state.pos[1], 0.0), rz(state.heading))
}

/// Where a carried object sits relative to the carrier's body frame.
fn carry_offset() -> Se3 {
    iso(P3::new(0.0, 0.42, 0.95), UnitQuaternion::identity())
}

/// Bursts of activity: 0 for part of every cycle (so seated people are sometimes exactly still).
fn burst(t: f64, period: f64, phase: f64) -> f64 {
    let s = (TAU * t / period + phase).sin();
    if s > 0.0 { s * s } else { 0.0 }
}

fn seated_pose(t: f64, phase: f64) -> Pose {
    let e1 = burst(t, 6.0, phase);
    let e2 = burst(t, 4.3, phase + 1.3);
    let eh = burst(t, 5.1, phase + 2.1);
    // Arms rest with the forearms level on the desk (shoulder + elbow >= ~1.65 rad keeps the
    // hands at or above the desk top); bursts raise and wave them (typing, gesturing,
    // reaching), as the people in TUM fr3 sitting_* do.
    let wave = |period: f64, ph: f64| 0.5 + 0.5 * (TAU * t / period + ph).sin();
    Pose {
        pelvis: 0.5,
        torso_pitch: -0.06,
        torso_yaw: 0.0,
        head_yaw: 0.5 * eh * (TAU * t / 2.7 + phase).sin(),
        head_pitch: 0.08 + 0.15 * eh * (TAU * t / 1.9).sin(),
        shoulder: [
            0.5 + e1 * 0.8 * wave(1.7, phase),
            0.5 + e2 * 0.9 * wave(1.3, phase),
        ],
        shoulder_out: [
            0.12 + 0.2 * e1,
            0.12 + 0.25 * e2 * (TAU * t / 2.1).sin().abs(),
        ],
        elbow: [
            1.2 + e1 * 0.5 * wave(1.1, 0.0),
            1.2 + e2 * 0.6 * wave(0.9, 1.0),
        ],
        hip: [FRAC_PI_2, FRAC_PI_2],
        knee: [FRAC_PI_2, FRAC_PI_2],
    }
}

/// A pose relative to the camera-facing direction: turn `pos` about z so that its -y axis
/// points at `eye` (horizontally).
fn facing(pos: P3, eye: &P3) -> Se3 {
    let d = eye - pos;
    iso(pos, rz(d.x.atan2(-d.y)))
}

impl Motion {
    /// World poses of an object's `n_parts` parts at time `t`, with the camera centre at `eye`
    /// (billboards face it).
    pub fn part_poses(&self, t: f64, eye: &P3, n_parts: usize, out: &mut Vec<Se3>) {
        out.clear();
        match self {
            Motion::Static(p) => out.extend(std::iter::repeat_n(*p, n_parts)),
            Motion::Walker { route, carry_until } => {
                let st = route.state(t);
                person_part_poses(&route_body(&st), &walking_pose(&st, t < *carry_until), out);
            }
            Motion::Seated { base, phase } => person_part_poses(base, &seated_pose(t, *phase), out),
            Motion::Carried {
                route,
                place_at,
                lower,
                place,
            } => {
                let arrive = route.arrival_time(*place_at);
                let held = |tt: f64| route_body(&route.state(tt)) * carry_offset();
                let p = if t < arrive {
                    held(t)
                } else if t < arrive + lower {
                    let f = smoothstep((t - arrive) / lower);
                    let a = held(arrive);
                    let tr = a.translation.vector.lerp(&place.translation.vector, f);
                    iso(tr, a.rotation.slerp(&place.rotation, f))
                } else {
                    *place
                };
                out.extend(std::iter::repeat_n(p, n_parts));
            }
            Motion::Lifted {
                base,
                lift,
                period,
                duration,
                phase,
            } => {
                let r = (t + phase).rem_euclid(*period);
                let f = if r < *duration {
                    (PI * r / duration).sin().powi(2)
                } else {
                    0.0
                };
                let p = if f == 0.0 {
                    *base
                } else {
                    base * iso(P3::new(0.0, -0.1 * f, lift * f), rx(0.9 * f))
                };
                out.extend(std::iter::repeat_n(p, n_parts));
            }
            Motion::Floating { base, amp, period } => {
                let w = |i: usize| (TAU * t / period[i] + i as f64).sin();
                let p = base + P3::new(amp.x * w(0), amp.y * w(1), amp.z * w(2));
                out.extend(std::iter::repeat_n(iso(p, rz(0.3 * w(1))), n_parts));
            }
            Motion::Driving { start, velocity } => {
                let yaw = if *velocity < 0.0 { PI } else { 0.0 };
                let p = P3::new(start[0], start[1] + velocity * t, 0.0);
                out.extend(std::iter::repeat_n(iso(p, rz(yaw)), n_parts));
            }
            Motion::Billboard { route, fixed, bob } => {
                let (xy, b) = match route {
                    Some(r) => {
                        let st = r.state(t);
                        let b = if *bob && st.walking {
                            0.015 * (2.0 * TAU * st.walked / STRIDE).cos()
                        } else {
                            0.0
                        };
                        (st.pos, b)
                    }
                    None => (*fixed, 0.0),
                };
                let p = facing(P3::new(xy[0], xy[1], b), eye);
                out.extend(std::iter::repeat_n(p, n_parts));
            }
        }
    }
}

/// Scene under construction: textures and objects.
pub struct Scene {
    /// The texture list that triangles index.
    pub textures: Vec<Texture>,
    /// The objects, in id order.
    pub objects: Vec<Object>,
}

/// The texture ids a person is dressed in.
#[derive(Clone, Copy, Debug)]
pub struct Outfit {
    /// The shirt's texture.
    pub shirt: u16,
    /// The trousers' texture.
    pub trousers: u16,
    /// The skin's texture (arms, hands, neck).
    pub skin: u16,
    /// The face's texture.
    pub head: u16,
    /// The hair's texture.
    pub hair: u16,
    /// The shoes' texture.
    pub shoes: u16,
}

impl Scene {
    /// An empty scene.
    pub fn new() -> Scene {
        Scene {
            textures: Vec::new(),
            objects: Vec::new(),
        }
    }

    /// Add a texture; returns its id.
    pub fn add_texture(&mut self, t: Texture) -> u16 {
        self.textures.push(t);
        (self.textures.len() - 1) as u16
    }

    /// Add a procedural texture of `style`, `w` x `h` texels; returns its id.
    pub fn paint(&mut self, style: Style, w: usize, h: usize, rng: &mut Pcg64Mcg) -> u16 {
        self.add_texture(procedural(style, w, h, rng))
    }

    /// Add an object with its parts and motion; its id is its position in `objects`.
    pub fn add(&mut self, name: &str, class_id: Option<u16>, parts: Vec<Part>, motion: Motion) {
        self.objects.push(Object {
            name: name.to_string(),
            class_id,
            parts,
            motion,
        });
    }

    /// A static single-part object at `pose`.
    pub fn add_static(&mut self, name: &str, class_id: Option<u16>, mesh: Mesh, pose: Se3) {
        self.add(
            name,
            class_id,
            vec![Part { name: "body", mesh }],
            Motion::Static(pose),
        );
    }

    /// Clothes for a person.
    pub fn outfit(
        &mut self,
        shirt: [f32; 3],
        trousers: [f32; 3],
        skin: [f32; 3],
        hair: [f32; 3],
        rng: &mut Pcg64Mcg,
    ) -> Outfit {
        Outfit {
            shirt: self.paint(Style::Cloth(shirt), 256, 128, rng),
            trousers: self.paint(Style::Cloth(trousers), 128, 128, rng),
            skin: self.paint(Style::Skin(skin), 64, 64, rng),
            head: self.paint(Style::Head(skin, hair), 128, 128, rng),
            hair: self.paint(Style::Cloth(hair), 64, 64, rng),
            shoes: self.paint(Style::Plain([0.12, 0.1, 0.09]), 32, 32, rng),
        }
    }
}

impl Default for Scene {
    fn default() -> Self {
        Self::new()
    }
}

/// The ten meshes of an articulated person, each in its joint's frame (limbs hang along -z).
pub fn person_parts(o: &Outfit) -> Vec<Part> {
    let mut torso = Mesh::prism(10, [0.2, 0.12], [0.17, 0.11], 0.55, o.shirt)
        .translated(P3::new(0.0, 0.0, 0.55));
    torso.extend(Mesh::prism(
        10,
        [0.17, 0.11],
        [0.18, 0.12],
        0.12,
        o.trousers,
    ));
    torso.extend(
        Mesh::prism(8, [0.05, 0.05], [0.055, 0.055], 0.06, o.skin)
            .translated(P3::new(0.0, 0.0, 0.6)),
    );
    let mut head = Mesh::ellipsoid(P3::new(0.085, 0.1, 0.12), 8, 12, o.head);
    // a shell of hair over the crown and the back of the head, so that the head has a person's
    // outline from every side (the face, at +y, stays free below the hairline)
    let mut hair = Mesh::ellipsoid(P3::new(0.093, 0.109, 0.128), 8, 12, o.hair);
    hair.tris.retain(|t| {
        let c = (t.p[0] + t.p[1] + t.p[2]) / 3.0;
        c.z > 0.045 || (c.y < -0.02 && c.z > -0.07)
    });
    head.extend(hair);
    let head = head.translated(P3::new(0.0, 0.0, 0.14));
    let upper = || Mesh::prism(8, [0.055, 0.055], [0.045, 0.045], 0.3, o.shirt);
    let fore = || {
        let mut m = Mesh::prism(8, [0.042, 0.042], [0.032, 0.032], 0.25, o.skin);
        m.extend(
            Mesh::ellipsoid(P3::new(0.02, 0.045, 0.075), 4, 8, o.skin)
                .translated(P3::new(0.0, 0.0, -0.31)),
        );
        m
    };
    let thigh = || Mesh::prism(8, [0.08, 0.085], [0.06, 0.065], 0.45, o.trousers);
    let shin = || {
        let mut m = Mesh::prism(8, [0.055, 0.06], [0.045, 0.05], 0.45, o.trousers);
        m.extend(Mesh::cuboid(
            P3::new(-0.045, -0.06, -0.52),
            P3::new(0.045, 0.17, -0.45),
            o.shoes,
        ));
        m
    };
    let meshes = [
        torso,
        head,
        upper(),
        fore(),
        upper(),
        fore(),
        thigh(),
        shin(),
        thigh(),
        shin(),
    ];
    PERSON_PARTS
        .iter()
        .zip(meshes)
        .map(|(name, mesh)| Part { name, mesh })
        .collect()
}

/// A chair in its own frame: seat centred above the origin, backrest at -y (a person sits
/// facing +y).
pub fn chair_mesh(tex: u16, metal: u16) -> Mesh {
    let mut m = Mesh::cuboid(P3::new(-0.23, -0.22, 0.42), P3::new(0.23, 0.22, 0.47), tex);
    m.extend(Mesh::cuboid(
        P3::new(-0.22, -0.25, 0.5),
        P3::new(0.22, -0.21, 0.92),
        tex,
    ));
    for (x, y) in [(-0.2, -0.2), (0.2, -0.2), (-0.2, 0.19), (0.2, 0.19)] {
        m.extend(Mesh::cuboid(
            P3::new(x - 0.015, y - 0.015, 0.0),
            P3::new(x + 0.015, y + 0.015, 0.42),
            metal,
        ));
    }
    m.extend(Mesh::cuboid(
        P3::new(-0.2, -0.24, 0.47),
        P3::new(-0.17, -0.21, 0.5),
        metal,
    ));
    m.extend(Mesh::cuboid(
        P3::new(0.17, -0.24, 0.47),
        P3::new(0.2, -0.21, 0.5),
        metal,
    ));
    m
}

/// A desk `w` x `d` with its top at `h`, origin at the floor centre.
pub fn desk_mesh(w: f64, d: f64, h: f64, top: u16, legs: u16) -> Mesh {
    let mut m = Mesh::cuboid(
        P3::new(-w / 2.0, -d / 2.0, h - 0.03),
        P3::new(w / 2.0, d / 2.0, h),
        top,
    );
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let (x, y) = (sx * (w / 2.0 - 0.05), sy * (d / 2.0 - 0.05));
        m.extend(Mesh::cuboid(
            P3::new(x - 0.025, y - 0.025, 0.0),
            P3::new(x + 0.025, y + 0.025, h - 0.03),
            legs,
        ));
    }
    m
}

/// A monitor facing -y standing on z = 0.
pub fn monitor_mesh(screen: u16, plastic: u16) -> Mesh {
    let mut m = Mesh::cuboid(
        P3::new(-0.27, -0.02, 0.12),
        P3::new(0.27, 0.02, 0.45),
        screen,
    );
    m.extend(Mesh::cuboid(
        P3::new(-0.03, 0.0, 0.0),
        P3::new(0.03, 0.04, 0.14),
        plastic,
    ));
    m.extend(Mesh::cuboid(
        P3::new(-0.12, -0.08, 0.0),
        P3::new(0.12, 0.1, 0.015),
        plastic,
    ));
    m
}

/// A laptop opened towards -y (the user sits at -y... the lid's back faces +y).
pub fn laptop_mesh(body: u16, screen: u16) -> Mesh {
    let mut m = Mesh::cuboid(P3::new(-0.17, -0.12, 0.0), P3::new(0.17, 0.12, 0.02), body);
    let lid = Mesh::cuboid(
        P3::new(-0.17, -0.012, 0.0),
        P3::new(0.17, 0.0, 0.24),
        screen,
    );
    m.extend(lid.transformed(&iso(P3::new(0.0, 0.12, 0.02), rx(-0.25))));
    m
}

/// Shelving `w` wide, `d` deep, `h` tall, with rows of books; origin at the floor centre.
pub fn shelf_mesh(w: f64, d: f64, h: f64, wood: u16, books: u16) -> Mesh {
    let mut m = Mesh::default();
    m.extend(Mesh::cuboid(
        P3::new(-w / 2.0, -d / 2.0, 0.0),
        P3::new(-w / 2.0 + 0.02, d / 2.0, h),
        wood,
    ));
    m.extend(Mesh::cuboid(
        P3::new(w / 2.0 - 0.02, -d / 2.0, 0.0),
        P3::new(w / 2.0, d / 2.0, h),
        wood,
    ));
    m.extend(Mesh::cuboid(
        P3::new(-w / 2.0, d / 2.0 - 0.01, 0.0),
        P3::new(w / 2.0, d / 2.0, h),
        wood,
    ));
    let n = 4;
    for k in 0..=n {
        let z = h * k as f64 / n as f64;
        m.extend(Mesh::cuboid(
            P3::new(-w / 2.0, -d / 2.0, z - 0.02),
            P3::new(w / 2.0, d / 2.0, z),
            wood,
        ));
        if k < n {
            // a row of books covering part of the shelf, its extent varying per shelf
            let x0 = -w / 2.0 + 0.03 + 0.07 * k as f64;
            let x1 = w / 2.0 - 0.03 - 0.2 * ((k * 7) % 3) as f64;
            let bh = h / n as f64 * (0.6 + 0.08 * k as f64);
            let mut row = Mesh::cuboid(
                P3::new(x0, -d / 2.0 + 0.03, z),
                P3::new(x1, d / 2.0 - 0.02, z + bh),
                books,
            );
            // each shelf shows a different part of the books texture
            for tri in &mut row.tris {
                for uv in &mut tri.uv {
                    uv[1] = (uv[1] + 0.25 * k as f32).fract().max(0.001);
                }
            }
            m.extend(row);
        }
    }
    m
}

/// A flat, camera-facing rectangle `w` x `h` standing on z = 0 (for cut-out people).
pub fn billboard_mesh(w: f64, h: f64, tex: u16) -> Mesh {
    let mut m = Mesh::default();
    m.quad(
        [
            P3::new(-w / 2.0, 0.0, 0.0),
            P3::new(w / 2.0, 0.0, 0.0),
            P3::new(w / 2.0, 0.0, h),
            P3::new(-w / 2.0, 0.0, h),
        ],
        tex,
        [0.0, 0.0],
        [1.0, 1.0],
    );
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn route_is_continuous_and_walks_at_its_speed() {
        let r = Route::ellipse([0.0, 1.0], [1.5, 0.5], 1.0, 0.3, false);
        let dt = 1.0 / 30.0;
        for k in 0..300 {
            let (a, b) = (r.state(k as f64 * dt), r.state((k + 1) as f64 * dt));
            let step = ((b.pos[0] - a.pos[0]).powi(2) + (b.pos[1] - a.pos[1]).powi(2)).sqrt();
            assert!(step <= 1.0 * dt + 1e-9, "step {step} at frame {k}");
            assert!((b.walked - a.walked - 1.0 * dt).abs() < 1e-9);
        }
    }

    #[test]
    fn seated_person_keeps_legs_still_and_moves_arms() {
        let m = Motion::Seated {
            base: Se3::identity(),
            phase: 0.0,
        };
        let (mut a, mut b) = (Vec::new(), Vec::new());
        let eye = P3::zeros();
        let mut arm_moved = false;
        for k in 0..90 {
            m.part_poses(k as f64 / 30.0, &eye, 10, &mut a);
            m.part_poses((k + 1) as f64 / 30.0, &eye, 10, &mut b);
            for leg in 6..10 {
                assert_eq!(a[leg], b[leg]);
            }
            assert_eq!(a[0], b[0]);
            arm_moved |= a[3] != b[3];
        }
        assert!(arm_moved);
    }

    #[test]
    fn carried_box_is_placed_and_stays() {
        let route = Route {
            points: vec![[-2.0, 1.0], [0.0, 1.0]],
            dwell: vec![0.5, 1.5],
            speed: 1.0,
            offset: 0.0,
        };
        let place = iso(P3::new(0.0, 1.5, 0.74), UnitQuaternion::identity());
        let m = Motion::Carried {
            route: route.clone(),
            place_at: 1,
            lower: 1.0,
            place,
        };
        assert!((route.arrival_time(1) - 2.5).abs() < 1e-12);
        let mut out = Vec::new();
        m.part_poses(4.0, &P3::zeros(), 1, &mut out);
        assert_eq!(out[0], place);
        m.part_poses(1.0, &P3::zeros(), 1, &mut out);
        assert!((out[0].translation.vector.z - 0.95).abs() < 1e-9);
    }
}
