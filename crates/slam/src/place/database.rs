//! The keyframe database (DBoW2 / ORB-SLAM `KeyFrameDatabase`): each keyframe's bag of words and
//! an inverted index from word to the keyframes holding it, queried for loop candidates.
//!
//! The vocabulary is trained online: once `first_training` keyframes exist, and again each time
//! the number of keyframes has grown by `retrain_factor`, so its words follow the map; every
//! stored vector is recomputed after a retraining.

use std::collections::{BTreeMap, BTreeSet};

use super::vocabulary::{BowVector, Vocabulary, VocabularyParams, WordId};
use crate::Descriptor;
use crate::data::KfId;

/// When the vocabulary is (re)trained.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DatabaseParams {
    /// How the vocabulary is trained.
    pub vocabulary: VocabularyParams,
    /// Keyframes needed for the first training (ORB-SLAM also detects no loop before its map
    /// holds 10 keyframes).
    pub first_training: usize,
    /// Retrain when the keyframes number this many times those of the last training.
    pub retrain_factor: f64,
}

impl Default for DatabaseParams {
    fn default() -> Self {
        Self {
            vocabulary: VocabularyParams::default(),
            first_training: 10,
            retrain_factor: 2.0,
        }
    }
}

/// Bags of words of the keyframes and the inverted index.
#[derive(Clone, Debug, Default)]
pub struct KeyFrameDatabase {
    vocabulary: Option<Vocabulary>,
    /// The vocabulary came from a file: never retrained.
    fixed_vocabulary: bool,
    trained_with: usize,
    bows: BTreeMap<KfId, BowVector>,
    inverted: BTreeMap<WordId, Vec<KfId>>,
    trainings: usize,
}

impl KeyFrameDatabase {
    /// An empty database; the vocabulary is trained once enough keyframes arrive.
    pub fn new() -> Self {
        Self::default()
    }

    /// A database over a given vocabulary (read from a file): no online training.
    pub fn with_vocabulary(v: Vocabulary) -> Self {
        Self {
            vocabulary: Some(v),
            fixed_vocabulary: true,
            ..Self::default()
        }
    }

    /// The vocabulary, once trained or given.
    pub fn vocabulary(&self) -> Option<&Vocabulary> {
        self.vocabulary.as_ref()
    }

    /// How many times the vocabulary was trained.
    pub fn trainings(&self) -> usize {
        self.trainings
    }

    /// Whether [`KeyFrameDatabase::train`] should run now that `keyframes` exist.
    pub fn needs_training(&self, keyframes: usize, p: &DatabaseParams) -> bool {
        if self.fixed_vocabulary {
            return false;
        }
        match self.vocabulary {
            None => keyframes >= p.first_training.max(1),
            Some(_) => keyframes as f64 >= self.trained_with as f64 * p.retrain_factor.max(1.01),
        }
    }

    /// (Re)train the vocabulary on these keyframes' descriptors and recompute every stored
    /// vector (those of keyframes not given are dropped).
    pub fn train(&mut self, keyframes: &[(KfId, &[Descriptor])], p: &DatabaseParams) {
        let docs: Vec<&[Descriptor]> = keyframes.iter().map(|k| k.1).collect();
        let Some(v) = Vocabulary::train(&docs, &p.vocabulary) else {
            return;
        };
        self.vocabulary = Some(v);
        self.trained_with = keyframes.len();
        self.trainings += 1;
        self.bows.clear();
        self.inverted.clear();
        for (id, d) in keyframes {
            self.add(*id, d);
        }
    }

    /// Store a keyframe's bag of words (replacing an older one). No-op before training.
    pub fn add(&mut self, kf: KfId, descriptors: &[Descriptor]) {
        let Some(v) = &self.vocabulary else { return };
        let bow = v.transform(descriptors);
        self.erase(kf);
        for (w, _) in &bow.0 {
            self.inverted.entry(*w).or_default().push(kf);
        }
        self.bows.insert(kf, bow);
    }

    /// Forget a keyframe (culled).
    pub fn erase(&mut self, kf: KfId) {
        if let Some(old) = self.bows.remove(&kf) {
            for (w, _) in &old.0 {
                if let Some(list) = self.inverted.get_mut(w) {
                    list.retain(|k| *k != kf);
                }
            }
        }
    }

    /// The bag-of-words vector of keyframe `kf`, if it is in the database.
    pub fn bow(&self, kf: KfId) -> Option<&BowVector> {
        self.bows.get(&kf)
    }

    /// Keyframes in the database.
    pub fn len(&self) -> usize {
        self.bows.len()
    }

    /// No keyframe in the database.
    pub fn is_empty(&self) -> bool {
        self.bows.is_empty()
    }

    /// Score of two stored keyframes (0 when either is missing).
    pub fn score(&self, a: KfId, b: KfId) -> f32 {
        match (self.bows.get(&a), self.bows.get(&b)) {
            (Some(x), Some(y)) => x.score(y),
            _ => 0.0,
        }
    }

    /// ORB-SLAM's `DetectLoopCandidates` for keyframe `kf`: keyframes sharing words with it,
    /// not in `excluded` (its covisible keyframes) and accepted by `usable`; of those sharing
    /// at least 80 % of the best count of common words, the ones scoring at least `min_score`;
    /// each is scored together with its `covisibles` (best 10) that also passed, and the best
    /// keyframe of every group whose accumulated score reaches 75 % of the best group's is
    /// returned (with its own score), best first.
    pub fn loop_candidates(
        &self,
        kf: KfId,
        excluded: &BTreeSet<KfId>,
        min_score: f32,
        usable: impl Fn(KfId) -> bool,
        covisibles: impl Fn(KfId) -> Vec<KfId>,
    ) -> Vec<(KfId, f32)> {
        let Some(bow) = self.bows.get(&kf) else {
            return Vec::new();
        };
        self.candidates(
            bow,
            |other| other != kf && !excluded.contains(&other) && usable(other),
            min_score,
            covisibles,
        )
    }

    /// ORB-SLAM's `DetectRelocalizationCandidates` for a frame's bag of words: the keyframes
    /// accepted by `usable` sharing words with it, grouped with their `covisibles` as
    /// [`KeyFrameDatabase::loop_candidates`] does (no minimum score), best first.
    pub fn relocalisation_candidates(
        &self,
        bow: &BowVector,
        usable: impl Fn(KfId) -> bool,
        covisibles: impl Fn(KfId) -> Vec<KfId>,
    ) -> Vec<(KfId, f32)> {
        self.candidates(bow, usable, 0.0, covisibles)
    }

    /// Keyframes sharing words with `bow` (accepted by `usable`), at least 80 % of the best
    /// count of common words, scored; groups with their covisibles; the best of every group
    /// reaching 75 % of the best group's accumulated score.
    fn candidates(
        &self,
        bow: &BowVector,
        usable: impl Fn(KfId) -> bool,
        min_score: f32,
        covisibles: impl Fn(KfId) -> Vec<KfId>,
    ) -> Vec<(KfId, f32)> {
        let mut common: BTreeMap<KfId, usize> = BTreeMap::new();
        for (w, _) in &bow.0 {
            for &other in self.inverted.get(w).map_or(&[][..], |v| v.as_slice()) {
                *common.entry(other).or_default() += 1;
            }
        }
        common.retain(|k, _| usable(*k));
        let Some(max_common) = common.values().copied().max() else {
            return Vec::new();
        };
        let min_common = (max_common as f32 * 0.8) as usize;
        // Score of every keyframe with enough common words (also those below min_score: they
        // still add to their neighbours' group score, as in ORB-SLAM).
        let scored: BTreeMap<KfId, f32> = common
            .iter()
            .filter(|(_, c)| **c > min_common)
            .map(|(k, _)| (*k, self.bows.get(k).map_or(0.0, |b| bow.score(b))))
            .collect();
        let mut groups: Vec<(f32, KfId, f32)> = Vec::new();
        for (&k, &s) in &scored {
            if s < min_score {
                continue;
            }
            let (mut acc, mut best) = (s, (s, k));
            for n in covisibles(k).into_iter().take(10) {
                if let Some(&sn) = scored.get(&n) {
                    acc += sn;
                    if sn > best.0 {
                        best = (sn, n);
                    }
                }
            }
            groups.push((acc, best.1, best.0));
        }
        let best_acc = groups.iter().map(|g| g.0).fold(0.0f32, f32::max);
        let mut out: Vec<(KfId, f32)> = Vec::new();
        for (acc, k, s) in groups {
            if acc >= 0.75 * best_acc && !out.iter().any(|o| o.0 == k) {
                out.push((k, s));
            }
        }
        out.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn descriptors(n: usize, seed: u64) -> Vec<Descriptor> {
        let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        (0..n)
            .map(|_| {
                std::array::from_fn(|_| {
                    s ^= s >> 12;
                    s ^= s << 25;
                    s ^= s >> 27;
                    (s.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 56) as u8
                })
            })
            .collect()
    }

    #[test]
    fn query_finds_the_revisited_keyframe_and_respects_exclusions() {
        // Keyframes 0..12 each see their own place; keyframe 12 revisits keyframe 2's place.
        let places: Vec<Vec<Descriptor>> = (0..12).map(|p| descriptors(200, 50 + p)).collect();
        let mut kfs: Vec<(KfId, Vec<Descriptor>)> =
            (0..12).map(|k| (k as KfId, places[k].clone())).collect();
        let mut revisit = places[2].clone();
        revisit.truncate(150);
        revisit.extend(descriptors(50, 7));
        kfs.push((12, revisit));
        let refs: Vec<(KfId, &[Descriptor])> =
            kfs.iter().map(|(k, d)| (*k, d.as_slice())).collect();
        let p = DatabaseParams::default();
        let mut db = KeyFrameDatabase::new();
        assert!(db.needs_training(refs.len(), &p));
        db.train(&refs, &p);
        assert_eq!(db.len(), 13);
        assert!(!db.needs_training(20, &p) && db.needs_training(26, &p));
        let none = BTreeSet::new();
        let c = db.loop_candidates(12, &none, 0.05, |_| true, |_| Vec::new());
        assert_eq!(c.first().map(|x| x.0), Some(2), "{c:?}");
        assert!(c[0].1 > 0.5, "{c:?}");
        // Excluded (covisible), unusable, or above the minimum score: no candidate.
        let excl: BTreeSet<KfId> = [2].into();
        assert!(
            db.loop_candidates(12, &excl, 0.05, |_| true, |_| Vec::new())
                .iter()
                .all(|x| x.0 != 2)
        );
        assert!(
            db.loop_candidates(12, &none, 0.05, |k| k != 2, |_| Vec::new())
                .iter()
                .all(|x| x.0 != 2)
        );
        assert!(
            db.loop_candidates(12, &none, 0.99, |_| true, |_| Vec::new())
                .is_empty()
        );
        // Erased keyframes are no longer found.
        db.erase(2);
        assert!(
            db.loop_candidates(12, &none, 0.05, |_| true, |_| Vec::new())
                .iter()
                .all(|x| x.0 != 2)
        );
    }
}
