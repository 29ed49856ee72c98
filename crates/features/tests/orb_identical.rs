//! Guard for speed work on the ORB extractor: keypoints and descriptors must stay bit-identical
//! (the SLAM results depend on them). Hashes of the full output on synthetic textures (and, when
//! the data is there, on the real TUM images) were recorded from the reference implementation,
//! and again when level pixels began to map to the image with pixel centres aligned (keypoint
//! positions moved on levels 1-7; descriptors unchanged).

use stillpoint_features::{Gray8, OrbExtractor, OrbFeatures, OrbParams};

/// FNV-1a over every keypoint field's bits and every descriptor byte.
fn hash(f: &OrbFeatures) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
        }
    };
    for k in &f.keypoints {
        for v in [k.x, k.y, k.angle, k.response, k.size] {
            eat(&v.to_bits().to_le_bytes());
        }
        eat(&[k.octave]);
    }
    for d in &f.descriptors {
        eat(d);
    }
    h
}

/// Smooth random blobs plus pixel noise, so FAST fires at both thresholds and in every cell.
fn texture(w: usize, h: usize, seed: u32) -> Gray8 {
    let mut s = seed;
    let mut rnd = || {
        s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (s >> 8) as f32 / (1u32 << 24) as f32
    };
    let mut f = vec![0f32; w * h];
    for _ in 0..(w * h / 60) {
        let (cx, cy, r, a) = (rnd() * w as f32, rnd() * h as f32, 2.0 + rnd() * 6.0, rnd());
        let (x0, x1) = ((cx - r).max(0.0) as usize, ((cx + r) as usize).min(w - 1));
        let (y0, y1) = ((cy - r).max(0.0) as usize, ((cy + r) as usize).min(h - 1));
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (dx, dy) = (x as f32 - cx, y as f32 - cy);
                if dx * dx + dy * dy < r * r {
                    f[y * w + x] += a * 90.0 - 45.0;
                }
            }
        }
    }
    let mut img = Gray8::new(w, h, 0);
    for (o, v) in img.data.iter_mut().zip(&f) {
        *o = (128.0 + v + rnd() * 6.0).clamp(0.0, 255.0) as u8;
    }
    img
}

fn run(img: &Gray8, n: usize) -> u64 {
    // ORB-SLAM's own extraction (no third FAST pass): these hashes pin that path.
    run_with(
        img,
        OrbParams {
            n_features: n,
            low_texture_th_fast: 0,
            ..OrbParams::default()
        },
    )
}

fn run_with(img: &Gray8, params: OrbParams) -> u64 {
    let mut orb = OrbExtractor::new(params);
    // twice, so buffers kept between frames cannot change the output
    let a = orb.extract(img);
    let b = orb.extract(img);
    assert_eq!(a, b);
    hash(&a)
}

#[test]
fn orb_output_is_unchanged_on_synthetic_textures() {
    let cases = [
        (640, 480, 7, 1000),
        (641, 479, 11, 1000),
        (320, 240, 3, 500),
        (1241, 376, 5, 2000),
    ];
    let got: Vec<u64> = cases
        .iter()
        .map(|&(w, h, seed, n)| run(&texture(w, h, seed), n))
        .collect();
    eprintln!("synthetic hashes {got:#x?}");
    let want: [u64; 4] = [
        0x71a827f1ab4eda57,
        0x117ea9a3f81d23e1,
        0x96fea6ed5962dd3c,
        0x6117e0c18308eac6,
    ];
    assert_eq!(got, want);
}

/// A flat image with faint noise and a few strong shapes: most cells have no corner at the
/// first two thresholds, so the third (noise-dependent) pass runs.
fn plain(w: usize, h: usize, seed: u32) -> Gray8 {
    let mut img = texture(w, h, seed);
    for (i, v) in img.data.iter_mut().enumerate() {
        let (x, y) = (i % w, i / w);
        let shape = (x / 97 + y / 83) % 5 == 0;
        *v = if shape {
            *v
        } else {
            (128 + (*v as i32 - 128) / 8) as u8
        };
    }
    img
}

#[test]
fn orb_output_with_the_default_parameters_is_unchanged() {
    // the project's defaults, third FAST pass (threshold from the image's noise) included
    let cases = [
        (texture(640, 480, 7), 1000),
        (plain(640, 480, 3), 1000),
        (plain(1241, 376, 5), 2000),
        (plain(752, 480, 9), 1000),
    ];
    let got: Vec<u64> = cases
        .iter()
        .map(|(img, n)| {
            run_with(
                img,
                OrbParams {
                    n_features: *n,
                    ..OrbParams::default()
                },
            )
        })
        .collect();
    eprintln!("default-parameter hashes {got:#x?}");
    // the plain images do take the third pass (else this test would pin nothing new)
    assert_ne!(got[1], run(&cases[1].0, 1000));
    let want: [u64; 4] = [
        0x71a827f1ab4eda57,
        0xe3bc75e33e7a2b8c,
        0x7757bdfeaee5a151,
        0xf1f0a025ff0502de,
    ];
    assert_eq!(got, want);
}

fn shared_dir() -> std::path::PathBuf {
    std::env::var_os("STILLPOINT_SHARED")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared"))
}

#[test]
#[ignore = "needs ../shared/data"]
fn orb_output_is_unchanged_on_real_images() {
    let d = shared_dir().join("data");
    let mut paths = vec![
        d.join("rgbd_pairs/pair/1.png"),
        d.join("rgbd_pairs/pair/2.png"),
    ];
    let mut tum: Vec<_> = std::fs::read_dir(d.join("tum/fr3_walking_halfsphere_first10_rgb/rgb"))
        .expect("TUM frames")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    tum.sort();
    paths.extend(tum.into_iter().take(4));
    // the three frame sizes ORB is timed on (640x480, KITTI 1241x376, EuRoC 752x480), with the
    // project's default parameters
    let sizes = [
        d.join("bow_loop_frames/1.png"),
        d.join("kitti/seq01_first51_left/image_0/000000.png"),
        d.join("euroc_mh01_2frames/mh01_frame1.png"),
    ];
    let got: Vec<u64> = paths
        .iter()
        .map(|p| run(&stillpoint_image::read_gray(p).expect("image"), 1000))
        .chain(sizes.iter().map(|p| {
            let img = stillpoint_image::read_gray(p).expect("image");
            run_with(&img, OrbParams::default())
        }))
        .collect();
    eprintln!("real hashes {got:#x?}");
    let want: [u64; 9] = [
        0xd14cf891ccde65f0,
        0xae5f42fac6de6996,
        0x83ce8be84e6bf038,
        0xe1b59ea6d0d469b7,
        0x52e7a4ec9302da46,
        0xaab7f2522a084a8a,
        0x22bdaf54902cb776,
        0x87db84ad6f911823,
        0xd2b2834eccec4984,
    ];
    assert_eq!(got, want);
}
