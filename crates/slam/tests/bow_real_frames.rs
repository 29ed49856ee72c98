//! Place recognition on real images: the 10 TUM fr1/desk frames of `../shared/data/bow_loop_frames`
//! (a walk round a desk; frame 10 comes back to where frame 1 was). The vocabulary is trained
//! on the frames themselves, as loop closing trains it on a sequence's keyframes.

use std::path::PathBuf;

use stillpoint_features::{OrbExtractor, OrbParams};
use stillpoint_slam::Descriptor;
use stillpoint_slam::place::{KeyFrameDatabase, Vocabulary, VocabularyParams};

fn shared() -> PathBuf {
    std::env::var_os("STILLPOINT_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared"))
}

fn frame_descriptors() -> Vec<Vec<Descriptor>> {
    let dir = shared().join("data/bow_loop_frames");
    let mut orb = OrbExtractor::new(OrbParams::default());
    (1..=10)
        .map(|i| {
            let p = dir.join(format!("{i}.png"));
            let img =
                stillpoint_image::read_gray(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            orb.extract(&img).descriptors
        })
        .collect()
}

#[test]
#[ignore = "needs ../shared/data"]
fn the_revisit_scores_above_every_other_place() {
    let descs = frame_descriptors();
    let docs: Vec<&[Descriptor]> = descs.iter().map(|d| d.as_slice()).collect();
    let voc = Vocabulary::train(&docs, &VocabularyParams::default()).expect("a vocabulary");
    let bows: Vec<_> = descs.iter().map(|d| voc.transform(d)).collect();
    let score = |a: usize, b: usize| bows[a - 1].score(&bows[b - 1]);
    for a in 1..=10 {
        let row: Vec<String> = (1..=10).map(|b| format!("{:.3}", score(a, b))).collect();
        eprintln!("{a:>2}: {}", row.join(" "));
    }
    // Frame 10 revisits frame 1; the other pairs more than two frames apart show other sides
    // of the desk (neighbours in the walk overlap, as consecutive keyframes do).
    let revisit = score(1, 10);
    let mut others = Vec::new();
    for a in 1..=10 {
        for b in a + 3..=10 {
            if (a, b) != (1, 10) {
                others.push(((a, b), score(a, b)));
            }
        }
    }
    let (worst_pair, worst) = others
        .iter()
        .copied()
        .max_by(|x, y| x.1.total_cmp(&y.1))
        .expect("pairs");
    eprintln!("revisit (1, 10) {revisit:.3}; best non-revisit {worst_pair:?} {worst:.3}");
    assert!(
        revisit > worst,
        "revisit {revisit} vs {worst_pair:?} {worst}"
    );
    // As a loop query: frame 10, with its neighbour 9 excluded (covisible), finds frame 1.
    let mut db = KeyFrameDatabase::new();
    let p = stillpoint_slam::place::DatabaseParams::default();
    let kfs: Vec<(u64, &[Descriptor])> = descs
        .iter()
        .enumerate()
        .map(|(i, d)| (i as u64 + 1, d.as_slice()))
        .collect();
    db.train(&kfs, &p);
    let excluded = [9u64].into();
    let c = db.loop_candidates(10, &excluded, 0.0, |_| true, |_| Vec::new());
    assert_eq!(c.first().map(|x| x.0), Some(1), "{c:?}");
    // Deterministic: the same frames train the same vocabulary.
    let again = Vocabulary::train(&docs, &VocabularyParams::default()).unwrap();
    assert_eq!(again.words(), voc.words());
    assert_eq!(again.transform(&descs[9]), bows[9]);
}
