//! Stage 1, detection: bag-of-words candidates and their covisibility consistency (ORB-SLAM's
//! `DetectLoop`).

use std::collections::BTreeSet;

use tracing::debug;

use super::{LoopCloser, lock};
use crate::data::{KfId, Map};

impl LoopCloser {
    /// ORB-SLAM `DetectLoop`: the candidates whose covisibility group has been consistent for
    /// `consistency` keyframes; `None` when there are none.
    pub(super) fn detect(&mut self, m: &Map, kf: KfId) -> Option<Vec<KfId>> {
        let ls = &self.s.loop_closing;
        let k = m.keyframes.get(&kf)?;
        let n = m.current_keyframes().count();
        if n < ls.min_keyframes
            || self
                .last_loop_kf
                .is_some_and(|l| kf < l + ls.keyframes_after_loop as KfId)
        {
            // No consistency carried across keyframes that were not checked.
            self.groups.clear();
            return None;
        }
        // The lowest score among the covisible keyframes sets the bar.
        let connected: BTreeSet<KfId> = k.connections.keys().copied().collect();
        // (Only neighbours already in the database: a missing one would score 0 and lower
        // the bar to nothing.)
        let db = lock(&self.db);
        let min_score = connected
            .iter()
            .filter(|&&c| db.bow(c).is_some())
            .map(|&c| db.score(kf, c))
            .fold(1.0f32, f32::min);
        let mut excluded = connected.clone();
        excluded.insert(kf);
        let epoch = k.map_epoch;
        // Older maps' keyframes too when merging: a place found there merges the two maps.
        // Monocular: within the map only with `monocular_loops` (corrected in Sim(3)).
        let older = ls.merge_maps;
        let same = !self.s.monocular || ls.monocular_loops;
        let candidates = db.loop_candidates(
            kf,
            &excluded,
            min_score,
            |c| {
                c < kf
                    && m.keyframes.get(&c).is_some_and(|x| {
                        !x.bad && ((same && x.map_epoch == epoch) || (older && x.map_epoch < epoch))
                    })
            },
            |c| {
                m.keyframes
                    .get(&c)
                    .map_or(Vec::new(), |x| x.best_covisibles(10))
            },
        );
        drop(db);
        if candidates.is_empty() {
            self.groups.clear();
            return None;
        }
        // Covisibility consistency: a candidate's group (it and its covisible keyframes) must
        // share a keyframe with a group of the previous keyframe's candidates.
        let mut current: Vec<(BTreeSet<KfId>, usize)> = Vec::new();
        let mut enough = Vec::new();
        let mut extended = vec![false; self.groups.len()];
        // A place in an older map skips this test: verification checks it in the keyframe's
        // covisible keyframes, then in the next keyframes (ORB-SLAM3's merge detection); a new
        // map may pass an older one's places in fewer keyframes than this test needs.
        let (older, candidates): (Vec<_>, Vec<_>) = candidates
            .into_iter()
            .partition(|(c, _)| m.keyframes.get(c).is_some_and(|x| x.map_epoch != epoch));
        enough.extend(older.iter().map(|(c, _)| *c));
        for &(c, _) in &candidates {
            let mut group: BTreeSet<KfId> = m
                .keyframes
                .get(&c)
                .map(|x| x.connections.keys().copied().collect())
                .unwrap_or_default();
            group.insert(c);
            let mut consistent_for_some = false;
            let mut enough_added = false;
            for (g, (prev, n_prev)) in self.groups.iter().enumerate() {
                if group.is_disjoint(prev) {
                    continue;
                }
                consistent_for_some = true;
                let n_cur = n_prev + 1;
                if !extended[g] {
                    current.push((group.clone(), n_cur));
                    extended[g] = true;
                }
                if n_cur >= ls.consistency && !enough_added {
                    enough.push(c);
                    enough_added = true;
                }
            }
            if !consistent_for_some {
                current.push((group, 0));
            }
        }
        debug!(
            keyframe = kf,
            candidates = candidates.len(),
            consistent = enough.len(),
            min_score,
            "loop candidates"
        );
        self.groups = current;
        (!enough.is_empty()).then_some(enough)
    }
}
