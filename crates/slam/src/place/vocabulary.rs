//! A bag of binary words (DBoW2-like): a vocabulary tree built by hierarchical k-medians over
//! 256-bit ORB descriptors, TF-IDF weights and the L1 score.
//!
//! ORB-SLAM loads a 145 MB vocabulary trained offline (ORBvoc.txt), which we cannot ship. This
//! one is trained from the sequence's own keyframes ([`Vocabulary::train`]), deterministically
//! (a seeded k-means++), and can also be read from a DBoW2 text file
//! ([`Vocabulary::from_dbow2_text`]) when a user has one.

use std::io::BufRead;

use crate::Descriptor;
use crate::hamming;

/// Index of a word (a leaf of the tree).
pub type WordId = u32;

/// A bag-of-words vector: (word, weight) sorted by word, weights L1-normalised.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BowVector(pub Vec<(WordId, f32)>);

impl BowVector {
    /// No word.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Number of words.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// DBoW2's L1 score, 1 - |a - b|_1 / 2 for L1-normalised vectors: in [0, 1], 1 for equal
    /// vectors, 0 when no word is shared.
    pub fn score(&self, other: &BowVector) -> f32 {
        let (a, b) = (&self.0, &other.0);
        let (mut i, mut j, mut s) = (0, 0, 0.0f32);
        while i < a.len() && j < b.len() {
            match a[i].0.cmp(&b[j].0) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => {
                    // |vi| + |wi| - |vi - wi| = 2 min(vi, wi) for positive weights.
                    s += a[i].1.min(b[j].1);
                    i += 1;
                    j += 1;
                }
            }
        }
        s
    }
}

/// How a vocabulary is trained.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VocabularyParams {
    /// Children per node (DBoW2 / ORBvoc: 10).
    pub branching: usize,
    /// Tree depth (ORBvoc: 6, for a million words trained on many sequences). One sequence's
    /// keyframes hold tens of thousands of descriptors; 4 levels (up to 10^4 words) keep a word
    /// to a few descriptors of about one landmark.
    pub levels: usize,
    /// A node with at most this many training descriptors becomes a word (DBoW2: 1, it
    /// splits down to single descriptors).
    pub leaf_size: usize,
    /// k-medians iterations per node at most (the assignment usually settles sooner).
    pub max_iterations: usize,
    /// At most this many descriptors are clustered (the training keyframes' descriptors are
    /// strided down to it); all of them still count for the IDF weights.
    pub max_training_descriptors: usize,
    /// Seed of the k-means++ seeding: the same descriptors give the same tree.
    pub seed: u64,
}

impl Default for VocabularyParams {
    fn default() -> Self {
        Self {
            branching: 10,
            levels: 4,
            leaf_size: 1,
            max_iterations: 10,
            max_training_descriptors: 60_000,
            seed: 0x5eed_b0b5,
        }
    }
}

const NO_WORD: u32 = u32::MAX;

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
struct Node {
    descriptor: Descriptor,
    first_child: u32,
    n_children: u32,
    word: u32,
}

/// The vocabulary tree with per-word IDF weights. Serialisable (map files carry it); a
/// deserialised one must pass [`Vocabulary::check`] before use.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Vocabulary {
    nodes: Vec<Node>,
    /// IDF weight per word.
    weights: Vec<f32>,
    /// Number of training documents (keyframes) the weights come from.
    documents: usize,
}

/// xorshift64*: small, deterministic, enough for seeding clusters.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        ((self.next() >> 11) % n.max(1) as u64) as usize
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Bitwise majority of descriptors (DBoW2 `FORB::meanValue`: a bit is set when at least half
/// the descriptors set it).
fn majority(descs: &[Descriptor], members: &[u32]) -> Descriptor {
    // Each byte's 8 bits spread to the 8 bytes of a u64 (bit i to byte i), so one add counts
    // them all; a byte lane holds up to 255, so the lanes go into `counts` every 255 members.
    const SPREAD: [u64; 256] = {
        let mut t = [0u64; 256];
        let mut v = 0;
        while v < 256 {
            let mut bit = 0;
            while bit < 8 {
                if v >> bit & 1 == 1 {
                    t[v] |= 1 << (8 * bit);
                }
                bit += 1;
            }
            v += 1;
        }
        t
    };
    let mut counts = [0u32; 256];
    for chunk in members.chunks(255) {
        let mut lanes = [0u64; 32];
        for &m in chunk {
            for (lane, byte) in lanes.iter_mut().zip(&descs[m as usize]) {
                *lane += SPREAD[*byte as usize];
            }
        }
        for (b, lane) in lanes.iter().enumerate() {
            for bit in 0..8 {
                counts[b * 8 + bit] += (lane >> (8 * bit) & 0xff) as u32;
            }
        }
    }
    let half = (members.len() as u32).div_ceil(2);
    let mut out = [0u8; 32];
    for (b, byte) in out.iter_mut().enumerate() {
        for bit in 0..8 {
            if counts[b * 8 + bit] >= half {
                *byte |= 1 << bit;
            }
        }
    }
    out
}

impl Vocabulary {
    /// Build the tree from training documents (one descriptor set per keyframe) and weight the
    /// words by their inverse document frequency over those documents. `None` without
    /// descriptors.
    pub fn train(documents: &[&[Descriptor]], p: &VocabularyParams) -> Option<Self> {
        let total: usize = documents.iter().map(|d| d.len()).sum();
        if total == 0 || p.branching < 2 || p.levels == 0 {
            return None;
        }
        let stride = total.div_ceil(p.max_training_descriptors.max(1)).max(1);
        let descs: Vec<Descriptor> = documents
            .iter()
            .flat_map(|d| d.iter())
            .step_by(stride)
            .copied()
            .collect();
        let mut voc = Vocabulary {
            nodes: vec![Node {
                descriptor: [0; 32],
                first_child: 0,
                n_children: 0,
                word: NO_WORD,
            }],
            weights: Vec::new(),
            documents: 0,
        };
        let mut rng = Rng(p.seed | 1);
        // Breadth-first: (node, members, level).
        let mut queue = std::collections::VecDeque::new();
        queue.push_back((
            0usize,
            (0..descs.len() as u32).collect::<Vec<u32>>(),
            0usize,
        ));
        while let Some((node, members, level)) = queue.pop_front() {
            if level >= p.levels || members.len() <= p.leaf_size.max(1) {
                voc.make_word(node);
                continue;
            }
            let clusters = if members.len() <= p.branching {
                members.iter().map(|&m| vec![m]).collect()
            } else {
                kmedians(&descs, &members, p.branching, p.max_iterations, &mut rng)
            };
            if clusters.len() <= 1 {
                // Identical descriptors cannot be split further.
                voc.make_word(node);
                continue;
            }
            let first = voc.nodes.len() as u32;
            voc.nodes[node].first_child = first;
            voc.nodes[node].n_children = clusters.len() as u32;
            for c in &clusters {
                voc.nodes.push(Node {
                    descriptor: majority(&descs, c),
                    first_child: 0,
                    n_children: 0,
                    word: NO_WORD,
                });
            }
            for (k, c) in clusters.into_iter().enumerate() {
                queue.push_back((first as usize + k, c, level + 1));
            }
        }
        voc.set_idf(documents);
        Some(voc)
    }

    fn make_word(&mut self, node: usize) {
        self.nodes[node].word = self.weights.len() as u32;
        self.weights.push(1.0);
    }

    /// IDF weight ln(N / n_i) of each word over the documents; a word no document holds gets
    /// ln(N) (rarer than any seen one).
    fn set_idf(&mut self, documents: &[&[Descriptor]]) {
        let n = documents.len().max(1) as f32;
        let mut holders = vec![0u32; self.weights.len()];
        let mut last_doc = vec![u32::MAX; self.weights.len()];
        for (d, doc) in documents.iter().enumerate() {
            for desc in doc.iter() {
                let w = self.word(desc) as usize;
                if last_doc[w] != d as u32 {
                    last_doc[w] = d as u32;
                    holders[w] += 1;
                }
            }
        }
        for (w, &h) in self.weights.iter_mut().zip(&holders) {
            *w = (n / h.max(1) as f32).ln();
        }
        self.documents = documents.len();
    }

    /// Whether the tree is usable: every child range lies after its node and inside the tree
    /// (so descending ends), every leaf names a word, every weight is finite. A vocabulary read
    /// from a file must pass this before [`Vocabulary::word`] or [`Vocabulary::transform`].
    pub fn check(&self) -> Result<(), String> {
        if self.nodes.is_empty() || self.weights.is_empty() {
            return Err("vocabulary without nodes or words".into());
        }
        for (i, n) in self.nodes.iter().enumerate() {
            if n.n_children == 0 {
                if n.word as usize >= self.weights.len() {
                    return Err(format!("vocabulary node {i}: leaf without a valid word"));
                }
            } else {
                let (first, end) = (
                    n.first_child as usize,
                    n.first_child as u64 + n.n_children as u64,
                );
                if first <= i || end > self.nodes.len() as u64 {
                    return Err(format!(
                        "vocabulary node {i}: children out of order or range"
                    ));
                }
            }
        }
        if let Some(w) = self.weights.iter().position(|w| !w.is_finite()) {
            return Err(format!("vocabulary word {w}: weight not finite"));
        }
        Ok(())
    }

    /// A 64-bit FNV-1a hash of the tree and the word weights: two vocabularies with the same
    /// fingerprint give the same words and bags of words (map files store it to refuse a map
    /// made with another vocabulary).
    pub fn fingerprint(&self) -> u64 {
        let mut h = crate::fnv1a64::START;
        for n in &self.nodes {
            h = crate::fnv1a64::update(h, &n.descriptor);
            for v in [n.first_child, n.n_children, n.word] {
                h = crate::fnv1a64::update(h, &v.to_le_bytes());
            }
        }
        for w in &self.weights {
            h = crate::fnv1a64::update(h, &w.to_bits().to_le_bytes());
        }
        h
    }

    /// Number of words (leaves).
    pub fn words(&self) -> usize {
        self.weights.len()
    }

    /// Number of documents the IDF weights were computed over.
    pub fn documents(&self) -> usize {
        self.documents
    }

    /// The word a descriptor falls in: the leaf reached by descending to the nearest child.
    pub fn word(&self, d: &Descriptor) -> WordId {
        let mut node = 0usize;
        loop {
            let n = &self.nodes[node];
            if n.n_children == 0 {
                return n.word;
            }
            let first = n.first_child as usize;
            let mut best = (u32::MAX, first);
            for c in first..first + n.n_children as usize {
                let dist = hamming(d, &self.nodes[c].descriptor);
                if dist < best.0 {
                    best = (dist, c);
                }
            }
            node = best.1;
        }
    }

    /// The TF-IDF bag of words of a descriptor set, L1-normalised.
    pub fn transform(&self, descs: &[Descriptor]) -> BowVector {
        let mut words: Vec<WordId> = descs.iter().map(|d| self.word(d)).collect();
        words.sort_unstable();
        let mut v: Vec<(WordId, f32)> = Vec::new();
        for w in words {
            let weight = self.weights[w as usize];
            match v.last_mut() {
                Some(last) if last.0 == w => last.1 += weight,
                _ => v.push((w, weight)),
            }
        }
        v.retain(|x| x.1 > 0.0);
        let sum: f32 = v.iter().map(|x| x.1).sum();
        if sum > 0.0 {
            v.iter_mut().for_each(|x| x.1 /= sum);
        }
        BowVector(v)
    }

    /// Read a DBoW2 text vocabulary (ORB-SLAM's `ORBvoc.txt`): a header `k L scoring weighting`,
    /// then one line per node after the root: `parent is_leaf d0 .. d31 weight`. Only the tree
    /// and the leaves' weights are used (our scoring is always TF-IDF / L1; other header
    /// types are warned about). Word ids are assigned breadth-first, not in the file's order:
    /// they are only used inside this program.
    pub fn from_dbow2_text(reader: impl BufRead) -> Result<Self, String> {
        let mut lines = reader.lines();
        let header = lines
            .next()
            .ok_or("empty vocabulary file")?
            .map_err(|e| e.to_string())?;
        let head: Vec<usize> = header
            .split_whitespace()
            .map(|t| {
                t.parse::<usize>()
                    .map_err(|e| format!("header {header:?}: {e}"))
            })
            .collect::<Result<_, _>>()?;
        if head.len() < 2 || head[0] < 2 || head[1] == 0 {
            return Err(format!(
                "header {header:?}: expected `k L scoring weighting`"
            ));
        }
        if head.get(2..4).is_some_and(|t| t != [0, 0]) {
            tracing::warn!(
                "vocabulary header {header:?}: scoring/weighting other than L1 / TF-IDF; \
                 the tree and weights are used with L1 scoring"
            );
        }
        // Parents come before their children in the file; children are gathered per parent.
        let mut parents: Vec<u32> = vec![u32::MAX];
        let mut raw: Vec<(Descriptor, bool, f32)> = vec![([0; 32], false, 0.0)];
        for (n, line) in lines.enumerate() {
            let line = line.map_err(|e| e.to_string())?;
            let t: Vec<&str> = line.split_whitespace().collect();
            if t.is_empty() {
                continue;
            }
            let bad = |what: &str| format!("node line {}: {what}", n + 2);
            if t.len() != 35 {
                return Err(bad("expected 35 fields"));
            }
            let parent: u32 = t[0].parse().map_err(|_| bad("parent"))?;
            if parent as usize >= raw.len() {
                return Err(bad("parent after child"));
            }
            let leaf = t[1] == "1";
            let mut d = [0u8; 32];
            for (k, b) in d.iter_mut().enumerate() {
                *b = t[2 + k].parse().map_err(|_| bad("descriptor byte"))?;
            }
            let w: f32 = t[34]
                .parse()
                .ok()
                .filter(|w: &f32| w.is_finite())
                .ok_or_else(|| bad("weight (a finite number)"))?;
            parents.push(parent);
            raw.push((d, leaf, w));
        }
        // Children of each node are contiguous in our layout: order nodes breadth-first.
        let mut children: Vec<Vec<u32>> = vec![Vec::new(); raw.len()];
        for (i, &p) in parents.iter().enumerate().skip(1) {
            children[p as usize].push(i as u32);
        }
        let mut voc = Vocabulary {
            nodes: Vec::with_capacity(raw.len()),
            weights: Vec::new(),
            documents: 0,
        };
        voc.nodes.push(Node {
            descriptor: [0; 32],
            first_child: 0,
            n_children: 0,
            word: NO_WORD,
        });
        let mut queue = std::collections::VecDeque::from([(0usize, 0usize)]);
        while let Some((src, dst)) = queue.pop_front() {
            let kids = &children[src];
            if kids.is_empty() {
                voc.nodes[dst].word = voc.weights.len() as u32;
                voc.weights.push(raw[src].2.max(0.0));
                continue;
            }
            let first = voc.nodes.len();
            voc.nodes[dst].first_child = first as u32;
            voc.nodes[dst].n_children = kids.len() as u32;
            for (k, &c) in kids.iter().enumerate() {
                voc.nodes.push(Node {
                    descriptor: raw[c as usize].0,
                    first_child: 0,
                    n_children: 0,
                    word: NO_WORD,
                });
                queue.push_back((c as usize, first + k));
            }
        }
        if voc.weights.is_empty() {
            return Err("vocabulary without words".into());
        }
        Ok(voc)
    }
}

/// k-medians of `members` into at most `k` clusters, k-means++ seeded (DBoW2 `HKmeansStep`).
/// Returns the non-empty clusters.
fn kmedians(
    descs: &[Descriptor],
    members: &[u32],
    k: usize,
    max_iterations: usize,
    rng: &mut Rng,
) -> Vec<Vec<u32>> {
    // k-means++: each next centre drawn with probability proportional to the squared distance
    // to the nearest centre chosen so far.
    let mut centres: Vec<Descriptor> = vec![descs[members[rng.below(members.len())] as usize]];
    let mut nearest: Vec<f64> = members
        .iter()
        .map(|&m| (hamming(&descs[m as usize], &centres[0]) as f64).powi(2))
        .collect();
    while centres.len() < k {
        let total: f64 = nearest.iter().sum();
        if total <= 0.0 {
            break; // all remaining descriptors equal a centre
        }
        let mut r = rng.unit() * total;
        let mut pick = members.len() - 1;
        for (i, d) in nearest.iter().enumerate() {
            if r < *d {
                pick = i;
                break;
            }
            r -= d;
        }
        let c = descs[members[pick] as usize];
        for (i, &m) in members.iter().enumerate() {
            let d = (hamming(&descs[m as usize], &c) as f64).powi(2);
            if d < nearest[i] {
                nearest[i] = d;
            }
        }
        centres.push(c);
    }
    let mut assign: Vec<usize> = vec![usize::MAX; members.len()];
    let mut clusters: Vec<Vec<u32>> = Vec::new();
    for it in 0..max_iterations.max(1) {
        let mut changed = false;
        for (i, &m) in members.iter().enumerate() {
            let d = &descs[m as usize];
            let mut best = (u32::MAX, 0);
            for (c, centre) in centres.iter().enumerate() {
                let h = hamming(d, centre);
                if h < best.0 {
                    best = (h, c);
                }
            }
            if assign[i] != best.1 {
                assign[i] = best.1;
                changed = true;
            }
        }
        clusters = vec![Vec::new(); centres.len()];
        for (i, &m) in members.iter().enumerate() {
            clusters[assign[i]].push(m);
        }
        if !changed && it > 0 {
            break;
        }
        for (c, members) in clusters.iter().enumerate() {
            if !members.is_empty() {
                centres[c] = majority(descs, members);
            }
        }
    }
    clusters.retain(|c| !c.is_empty());
    clusters
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn majority_sets_the_bits_at_least_half_the_members_set() {
        let descs = random_descriptors(700, 5);
        for n in [1usize, 2, 3, 254, 255, 256, 511, 700] {
            // Every other descriptor, so members are not simply 0..n.
            let members: Vec<u32> = (0..n as u32).map(|i| (i * 2) % 700).collect();
            let got = majority(&descs, &members);
            for bit in 0..256 {
                let set = members
                    .iter()
                    .filter(|&&m| descs[m as usize][bit / 8] >> (bit % 8) & 1 == 1)
                    .count();
                let want = 2 * set >= n;
                assert_eq!(
                    got[bit / 8] >> (bit % 8) & 1 == 1,
                    want,
                    "{n} members, bit {bit}"
                );
            }
        }
    }

    /// `n` random descriptors from a seed.
    fn random_descriptors(n: usize, seed: u64) -> Vec<Descriptor> {
        let mut r = Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1);
        (0..n)
            .map(|_| std::array::from_fn(|_| (r.next() >> 56) as u8))
            .collect()
    }

    /// A copy of `d` with `flips` bits flipped (a re-observation of the same landmark).
    fn noisy(d: &[Descriptor], flips: usize, seed: u64) -> Vec<Descriptor> {
        let mut r = Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1);
        d.iter()
            .map(|x| {
                let mut y = *x;
                for _ in 0..flips {
                    let bit = r.below(256);
                    y[bit / 8] ^= 1 << (bit % 8);
                }
                y
            })
            .collect()
    }

    #[test]
    fn revisited_places_score_higher_and_training_is_deterministic() {
        // Five "places", each 300 landmarks; documents are noisy views of one place.
        let places: Vec<Vec<Descriptor>> =
            (0..5).map(|p| random_descriptors(300, 11 + p)).collect();
        let docs: Vec<Vec<Descriptor>> = (0..10)
            .map(|i| noisy(&places[i % 5], 6, 100 + i as u64))
            .collect();
        let refs: Vec<&[Descriptor]> = docs.iter().map(|d| d.as_slice()).collect();
        let p = VocabularyParams::default();
        let voc = Vocabulary::train(&refs, &p).expect("a vocabulary");
        assert!(voc.words() > 100, "{} words", voc.words());
        let query = voc.transform(&noisy(&places[2], 8, 999));
        let scores: Vec<f32> = (0..5)
            .map(|k| query.score(&voc.transform(&docs[k])))
            .collect();
        let same = scores[2];
        let best_other = scores
            .iter()
            .enumerate()
            .filter(|(k, _)| *k != 2)
            .map(|(_, s)| *s)
            .fold(0.0, f32::max);
        assert!(same > 0.3 && same > 5.0 * best_other, "{scores:?}");
        // A vector scores 1 with itself; the score is symmetric.
        let v = voc.transform(&docs[0]);
        assert!((v.score(&v) - 1.0).abs() < 1e-5);
        assert!((v.score(&query) - query.score(&v)).abs() < 1e-6);
        // Same input, same tree, same vectors.
        let again = Vocabulary::train(&refs, &p).unwrap();
        assert_eq!(again.words(), voc.words());
        assert_eq!(again.transform(&docs[3]), voc.transform(&docs[3]));
    }

    #[test]
    fn degenerate_input_gives_no_vocabulary_or_a_single_word() {
        assert!(Vocabulary::train(&[], &VocabularyParams::default()).is_none());
        let same = vec![[3u8; 32]; 50];
        let voc = Vocabulary::train(&[&same], &VocabularyParams::default()).unwrap();
        assert_eq!(voc.words(), 1);
        // One document holding the only word: IDF ln(1/1) = 0, an empty vector.
        assert!(voc.transform(&same).is_empty());
    }

    #[test]
    fn dbow2_text_round_trip_of_a_tiny_tree() {
        // Root with two leaves (k = 2, L = 1).
        let a = [0u8; 32];
        let b = [255u8; 32];
        let line = |d: &Descriptor, w: f32| {
            let bytes: Vec<String> = d.iter().map(|x| x.to_string()).collect();
            format!("0 1 {} {w}", bytes.join(" "))
        };
        let text = format!("2 1 0 0\n{}\n{}\n", line(&a, 0.5), line(&b, 2.0));
        let voc = Vocabulary::from_dbow2_text(text.as_bytes()).expect("parsed");
        assert_eq!(voc.words(), 2);
        let mut near_b = b;
        near_b[0] = 0;
        assert_ne!(voc.word(&a), voc.word(&near_b));
        let v = voc.transform(&[a, near_b]);
        assert_eq!(v.len(), 2);
        assert!((v.0.iter().map(|x| x.1).sum::<f32>() - 1.0).abs() < 1e-6);
        assert!(Vocabulary::from_dbow2_text("x y\n".as_bytes()).is_err());
        assert!(Vocabulary::from_dbow2_text("2 1 0 0\n5 1 0\n".as_bytes()).is_err());
        // An infinite weight would make every bag of words NaN.
        let inf = format!("2 1 0 0\n{}\n{}\n", line(&a, 0.5), line(&b, f32::INFINITY));
        assert!(Vocabulary::from_dbow2_text(inf.as_bytes()).is_err());
    }
}
