//! Pose-graph optimisation (ORB-SLAM's essential graph): over SE3, the scale fixed as for RGB-D
//! and stereo, and over Sim(3) for monocular maps, whose scale drifts. Vertices are
//! world-to-camera poses, each edge a measured relative pose.
//!
//! Levenberg-Marquardt on the normal equations; the system is sparse (a chain of keyframes plus
//! a few loop and covisibility edges), so it is reordered by reverse Cuthill-McKee and solved by
//! an envelope (profile) Cholesky: the loop edges only widen the rows they touch.

use nalgebra::{Matrix3, Matrix6, SMatrix, SVector, Vector3, Vector6};
use stillpoint_geometry::{Se3, Sim3, skew};

use super::retract;

/// One relative measurement: `t_ij` = X_iw * X_jw⁻¹, camera j seen from camera i (a pose, or a
/// similarity in a monocular map).
#[derive(Clone, Copy, Debug)]
pub struct GraphEdge<V> {
    /// Index of camera i in `Graph::poses`.
    pub i: usize,
    /// Index of camera j.
    pub j: usize,
    /// The measured transform from camera j to camera i.
    pub t_ij: V,
    /// Information weight (ORB-SLAM: identity for every edge).
    pub weight: f64,
}

/// World-to-camera transforms, which of them stay fixed, and the edges.
#[derive(Clone, Debug)]
pub struct Graph<V> {
    /// World-to-camera transforms.
    pub poses: Vec<V>,
    /// Per pose: held fixed.
    pub fixed: Vec<bool>,
    /// The relative measurements.
    pub edges: Vec<GraphEdge<V>>,
}

impl<V> Default for Graph<V> {
    fn default() -> Self {
        Self {
            poses: Vec::new(),
            fixed: Vec::new(),
            edges: Vec::new(),
        }
    }
}

/// The essential graph over SE3 (RGB-D, stereo).
pub type PoseGraph = Graph<Se3>;
/// An edge of [`PoseGraph`].
pub type PoseGraphEdge = GraphEdge<Se3>;
/// The essential graph of a monocular map (ORB-SLAM's, in Sim(3)): a loop spreads the scale
/// the map lost on its way along with the pose.
pub type Sim3Graph = Graph<Sim3>;
/// An edge of [`Sim3Graph`].
pub type Sim3Edge = GraphEdge<Sim3>;

/// What the optimiser did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseGraphReport {
    /// Sum of weighted squared errors before.
    pub initial_cost: f64,
    /// The same after.
    pub final_cost: f64,
    /// Gauss-Newton iterations run.
    pub iterations: usize,
}

/// Rotation log with the translation as is: the error coordinates (ω, υ) matching [`retract`].
fn error_of(e: &Se3) -> Vector6<f64> {
    let w = e.rotation.scaled_axis();
    let t = e.translation.vector;
    Vector6::new(w.x, w.y, w.z, t.x, t.y, t.z)
}

/// Inverse of SO3's right Jacobian at φ.
fn so3_right_jacobian_inv(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta = phi.norm();
    let k = skew(phi);
    if theta < 1e-6 {
        return Matrix3::identity() + 0.5 * k + k * k / 12.0;
    }
    let c = 1.0 / (theta * theta) - (1.0 + theta.cos()) / (2.0 * theta * theta.sin());
    Matrix3::identity() + 0.5 * k + c * k * k
}

/// Adjoint of `x` in (ω, υ) coordinates: exp(δ) x = x exp(Ad(x⁻¹) δ).
fn adjoint(x: &Se3) -> Matrix6<f64> {
    let r = *x.rotation.to_rotation_matrix().matrix();
    let t = x.translation.vector;
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(&(skew(&t) * r));
    m
}

/// Residual and Jacobians (w.r.t. left perturbations of T_iw and T_jw) of one edge.
fn linearise(g: &PoseGraph, e: &PoseGraphEdge) -> (Vector6<f64>, Matrix6<f64>, Matrix6<f64>) {
    let x = g.poses[e.i] * g.poses[e.j].inverse();
    let err = e.t_ij.inverse() * x;
    let r = error_of(&err);
    // d r / d ξ for err · exp(ξ): J_r⁻¹ on the rotation, R_err on the translation.
    let mut d = Matrix6::zeros();
    d.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&so3_right_jacobian_inv(&Vector3::new(r[0], r[1], r[2])));
    d.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(err.rotation.to_rotation_matrix().matrix());
    let ji = d * adjoint(&x.inverse());
    (r, ji, -d)
}

fn cost(g: &PoseGraph) -> f64 {
    g.edges
        .iter()
        .map(|e| {
            let x = g.poses[e.i] * g.poses[e.j].inverse();
            e.weight * error_of(&(e.t_ij.inverse() * x)).norm_squared()
        })
        .sum()
}

/// Optimise the free poses for at most `iterations` Levenberg-Marquardt steps. A graph without
/// a fixed pose gets its first pose fixed (the gauge).
pub fn optimize_pose_graph(g: &mut PoseGraph, iterations: usize) -> PoseGraphReport {
    levenberg_marquardt::<6, _>(g, iterations)
}

/// A vertex the Levenberg-Marquardt solver moves, `D` parameters: the edge residuals of a
/// [`Graph`] of them, their Jacobians, and the step.
trait GraphVertex<const D: usize>: Clone {
    /// Residual and Jacobians w.r.t. both ends of edge `e`.
    fn linearise(
        g: &Graph<Self>,
        e: &GraphEdge<Self>,
    ) -> (SVector<f64, D>, SMatrix<f64, D, D>, SMatrix<f64, D, D>);
    /// Sum of the weighted squared residuals.
    fn cost(g: &Graph<Self>) -> f64;
    /// The vertex moved by `d` (the tangent step of its left perturbation).
    fn retract(&self, d: &SVector<f64, D>) -> Self;
}

impl GraphVertex<6> for Se3 {
    fn linearise(g: &PoseGraph, e: &PoseGraphEdge) -> (Vector6<f64>, Matrix6<f64>, Matrix6<f64>) {
        linearise(g, e)
    }
    fn cost(g: &PoseGraph) -> f64 {
        cost(g)
    }
    fn retract(&self, d: &Vector6<f64>) -> Se3 {
        retract(self, d)
    }
}

fn levenberg_marquardt<const D: usize, V: GraphVertex<D>>(
    g: &mut Graph<V>,
    iterations: usize,
) -> PoseGraphReport {
    let n = g.poses.len();
    g.fixed.resize(n, false);
    if !g.fixed.iter().any(|&f| f) && n > 0 {
        g.fixed[0] = true;
    }
    g.edges.retain(|e| e.i < n && e.j < n && e.i != e.j);
    let fixed = &g.fixed;
    // Free vertices, reordered to keep the Cholesky envelope narrow.
    let free: Vec<usize> = (0..n).filter(|&v| !fixed[v]).collect();
    let mut slot = vec![usize::MAX; n];
    for (k, &v) in free.iter().enumerate() {
        slot[v] = k;
    }
    let mut neighbours: Vec<Vec<usize>> = vec![Vec::new(); free.len()];
    for e in &g.edges {
        let (a, b) = (slot[e.i], slot[e.j]);
        if a != usize::MAX && b != usize::MAX {
            neighbours[a].push(b);
            neighbours[b].push(a);
        }
    }
    for nb in &mut neighbours {
        nb.sort_unstable();
        nb.dedup();
    }
    let order = reverse_cuthill_mckee(&neighbours);
    let mut position = vec![0usize; free.len()];
    for (p, &k) in order.iter().enumerate() {
        position[k] = p;
    }
    // Block row b (in the new order) starts at the block of its earliest neighbour.
    let first_block: Vec<usize> = order
        .iter()
        .map(|&k| {
            neighbours[k]
                .iter()
                .map(|&m| position[m])
                .chain(std::iter::once(position[k]))
                .min()
                .unwrap_or(position[k])
        })
        .collect();
    let dim = D * free.len();
    let index = |v: usize| -> Option<usize> {
        let k = slot[v];
        (k != usize::MAX).then(|| D * position[k])
    };

    let initial_cost = V::cost(g);
    let mut current = initial_cost;
    let mut lambda = 1e-4;
    let mut done = 0;
    for _ in 0..iterations {
        if free.is_empty() {
            break;
        }
        done += 1;
        let mut h = Envelope::new(dim, D, &first_block);
        let mut b = vec![0.0; dim];
        for e in &g.edges {
            let (r, ji, jj) = V::linearise(g, e);
            let weight = e.weight;
            let blocks = [(index(e.i), ji), (index(e.j), jj)];
            for (ia, ja) in &blocks {
                let Some(ia) = *ia else { continue };
                let g_a = ja.transpose() * r * weight;
                for (k, v) in g_a.iter().enumerate() {
                    b[ia + k] += v;
                }
                for (ib, jb) in &blocks {
                    let Some(ib) = *ib else { continue };
                    if ib > ia {
                        continue; // lower triangle only
                    }
                    let hab = ja.transpose() * jb * weight;
                    for r_ in 0..D {
                        for c in 0..D {
                            if ia + r_ >= ib + c {
                                h.add(ia + r_, ib + c, hab[(r_, c)]);
                            }
                        }
                    }
                }
            }
        }
        // Levenberg-Marquardt: retry with more damping until the cost goes down.
        let mut improved = false;
        for _ in 0..10 {
            let mut damped = h.clone();
            for i in 0..dim {
                let d = damped.get(i, i);
                damped.set(i, i, d + lambda * d.max(1e-9));
            }
            let Some(step) = damped.solve(&b) else {
                lambda *= 10.0;
                continue;
            };
            let backup = g.poses.clone();
            for &v in &free {
                let Some(i0) = index(v) else { continue };
                let d = SVector::<f64, D>::from_fn(|k, _| -step[i0 + k]);
                g.poses[v] = g.poses[v].retract(&d);
            }
            let c = V::cost(g);
            if c < current {
                current = c;
                lambda = (lambda / 10.0).max(1e-9);
                improved = true;
                break;
            }
            g.poses = backup;
            lambda *= 10.0;
        }
        if !improved || current < 1e-18 {
            break;
        }
    }
    PoseGraphReport {
        initial_cost,
        final_cost: current,
        iterations: done,
    }
}

/// Error coordinates of a similarity near the identity: rotation log, translation, log scale.
fn sim3_error(e: &Sim3) -> SVector<f64, 7> {
    let w = e.rigid.rotation.scaled_axis();
    let t = e.rigid.translation.vector;
    SVector::<f64, 7>::from_column_slice(&[w.x, w.y, w.z, t.x, t.y, t.z, e.scale.ln()])
}

/// The similarity of a tangent step (ω, υ, σ): rotation exp(ω), translation υ, scale e^σ.
fn sim3_step(d: &SVector<f64, 7>) -> Sim3 {
    Sim3 {
        scale: d[6].exp(),
        rigid: Se3::from_parts(
            Vector3::new(d[3], d[4], d[5]).into(),
            nalgebra::UnitQuaternion::from_scaled_axis(Vector3::new(d[0], d[1], d[2])),
        ),
    }
}

fn sim3_residual(e: &Sim3Edge, si: &Sim3, sj: &Sim3) -> SVector<f64, 7> {
    sim3_error(&e.t_ij.inverse().compose(&si.compose(&sj.inverse())))
}

/// Jacobians by central differences: 7x7 per end, cheap beside the solve (once per loop).
impl GraphVertex<7> for Sim3 {
    fn linearise(
        g: &Sim3Graph,
        e: &Sim3Edge,
    ) -> (SVector<f64, 7>, SMatrix<f64, 7, 7>, SMatrix<f64, 7, 7>) {
        let (si, sj) = (g.poses[e.i], g.poses[e.j]);
        let r = sim3_residual(e, &si, &sj);
        let h = 1e-6;
        let mut ji = SMatrix::<f64, 7, 7>::zeros();
        let mut jj = SMatrix::<f64, 7, 7>::zeros();
        for k in 0..7 {
            let mut d = SVector::<f64, 7>::zeros();
            d[k] = h;
            let (plus, minus) = (sim3_step(&d), sim3_step(&-d));
            let di = sim3_residual(e, &plus.compose(&si), &sj)
                - sim3_residual(e, &minus.compose(&si), &sj);
            let dj = sim3_residual(e, &si, &plus.compose(&sj))
                - sim3_residual(e, &si, &minus.compose(&sj));
            ji.set_column(k, &(di / (2.0 * h)));
            jj.set_column(k, &(dj / (2.0 * h)));
        }
        (r, ji, jj)
    }
    fn cost(g: &Sim3Graph) -> f64 {
        g.edges
            .iter()
            .map(|e| e.weight * sim3_residual(e, &g.poses[e.i], &g.poses[e.j]).norm_squared())
            .sum()
    }
    fn retract(&self, d: &SVector<f64, 7>) -> Sim3 {
        sim3_step(d).compose(self)
    }
}

/// [`optimize_pose_graph`] in Sim(3): the free similarities for at most `iterations`
/// Levenberg-Marquardt steps; without a fixed pose the first is fixed.
pub fn optimize_sim3_graph(g: &mut Sim3Graph, iterations: usize) -> PoseGraphReport {
    levenberg_marquardt::<7, _>(g, iterations)
}

/// Reverse Cuthill-McKee order of an undirected graph (adjacency lists): breadth-first from a
/// low-degree vertex of each component, neighbours by increasing degree, then reversed.
fn reverse_cuthill_mckee(adj: &[Vec<usize>]) -> Vec<usize> {
    let n = adj.len();
    let mut seen = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut by_degree: Vec<usize> = (0..n).collect();
    by_degree.sort_by_key(|&v| (adj[v].len(), v));
    for &start in &by_degree {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        let mut queue = std::collections::VecDeque::from([start]);
        while let Some(v) = queue.pop_front() {
            order.push(v);
            let mut next: Vec<usize> = adj[v].iter().copied().filter(|&u| !seen[u]).collect();
            next.sort_by_key(|&u| (adj[u].len(), u));
            for u in next {
                seen[u] = true;
                queue.push_back(u);
            }
        }
    }
    order.reverse();
    order
}

/// A symmetric matrix stored by its lower envelope: row r holds columns first[r]..=r.
#[derive(Clone, Debug)]
struct Envelope {
    first: Vec<usize>,
    start: Vec<usize>,
    values: Vec<f64>,
}

impl Envelope {
    /// `first_block[b]`: the first `block` x `block` block column of block row b.
    fn new(dim: usize, block: usize, first_block: &[usize]) -> Self {
        let mut first = Vec::with_capacity(dim);
        let mut start = Vec::with_capacity(dim + 1);
        let mut len = 0;
        for r in 0..dim {
            let f = block * first_block[r / block];
            first.push(f);
            start.push(len);
            len += r + 1 - f;
        }
        start.push(len);
        Self {
            first,
            start,
            values: vec![0.0; len],
        }
    }

    fn at(&self, r: usize, c: usize) -> Option<usize> {
        (c >= self.first[r] && c <= r).then(|| self.start[r] + c - self.first[r])
    }

    fn add(&mut self, r: usize, c: usize, v: f64) {
        if let Some(k) = self.at(r, c) {
            self.values[k] += v;
        }
    }

    fn get(&self, r: usize, c: usize) -> f64 {
        self.at(r, c).map_or(0.0, |k| self.values[k])
    }

    fn set(&mut self, r: usize, c: usize, v: f64) {
        if let Some(k) = self.at(r, c) {
            self.values[k] = v;
        }
    }

    /// Solve A x = b by an in-place Cholesky factorisation of the envelope; `None` when A is
    /// not positive definite.
    fn solve(mut self, b: &[f64]) -> Option<Vec<f64>> {
        let n = self.first.len();
        for r in 0..n {
            let fr = self.first[r];
            for c in fr..=r {
                let fc = self.first[c];
                let k0 = fr.max(fc);
                let (sr, sc) = (self.start[r] - fr, self.start[c] - fc);
                let mut s = self.values[sr + c];
                for k in k0..c {
                    s -= self.values[sr + k] * self.values[sc + k];
                }
                if c == r {
                    if s.is_nan() || s <= 0.0 {
                        return None;
                    }
                    self.values[sr + r] = s.sqrt();
                } else {
                    self.values[sr + c] = s / self.values[sc + c];
                }
            }
        }
        // L y = b, then Lᵀ x = y.
        let mut y = b.to_vec();
        for r in 0..n {
            let (fr, sr) = (self.first[r], self.start[r]);
            let row = &self.values[sr..sr + r - fr];
            let dot: f64 = row.iter().zip(&y[fr..r]).map(|(l, x)| l * x).sum();
            y[r] = (y[r] - dot) / self.values[sr + r - fr];
        }
        for r in (0..n).rev() {
            let (fr, sr) = (self.first[r], self.start[r]);
            y[r] /= self.values[sr + r - fr];
            let yr = y[r];
            let row = &self.values[sr..sr + r - fr];
            for (x, l) in y[fr..r].iter_mut().zip(row) {
                *x -= l * yr;
            }
        }
        y.iter().all(|v| v.is_finite()).then_some(y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Camera-to-world poses around a circle of radius 3 m, looking outwards.
    fn circle(n: usize) -> Vec<Se3> {
        (0..n)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / n as f64;
                Se3::new(
                    Vector3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.1 * (3.0 * a).sin()),
                    Vector3::new(0.0, a, 0.0),
                )
            })
            .collect()
    }

    fn position_error(a: &[Se3], b: &[Se3]) -> f64 {
        // Both gauges fix pose 0, so poses compare directly.
        a.iter()
            .zip(b)
            .map(|(x, y)| (x.inverse().translation.vector - y.inverse().translation.vector).norm())
            .fold(0.0, f64::max)
    }

    /// Dead reckoning with a biased step: the drifted poses, and the measured steps.
    fn drifted(truth: &[Se3]) -> (Vec<Se3>, Vec<Se3>) {
        let bias = Se3::new(
            Vector3::new(0.01, -0.004, 0.006),
            Vector3::new(0.002, -0.003, 0.004),
        );
        let mut poses = vec![truth[0]];
        let mut steps = Vec::new();
        for k in 1..truth.len() {
            let measured = truth[k - 1] * truth[k].inverse() * bias;
            poses.push(measured.inverse() * poses[k - 1]);
            steps.push(measured);
        }
        (poses, steps)
    }

    fn edge(i: usize, j: usize, t_ij: Se3) -> PoseGraphEdge {
        PoseGraphEdge {
            i,
            j,
            t_ij,
            weight: 1.0,
        }
    }

    #[test]
    fn drifted_poses_converge_onto_consistent_edges() {
        // Every edge exact (chain, loop, a few chords); the start is the drifted dead
        // reckoning: the optimiser must find the truth again.
        let n = 60;
        let truth: Vec<Se3> = circle(n).iter().map(|p| p.inverse()).collect();
        let (start, _) = drifted(&truth);
        let rel = |i: usize, j: usize| truth[i] * truth[j].inverse();
        let mut edges: Vec<PoseGraphEdge> = (1..n).map(|k| edge(k - 1, k, rel(k - 1, k))).collect();
        edges.push(edge(n - 1, 0, rel(n - 1, 0)));
        for k in (2..n).step_by(7) {
            edges.push(edge(k - 2, k, rel(k - 2, k)));
        }
        let before = position_error(&start, &truth);
        let mut g = PoseGraph {
            poses: start,
            fixed: vec![false; n],
            edges,
        };
        g.fixed[0] = true;
        let report = optimize_pose_graph(&mut g, 20);
        let after = position_error(&g.poses, &truth);
        assert!(before > 0.5, "drift {before}");
        assert!(after < 1e-6, "before {before} after {after} ({report:?})");
        assert_eq!(g.poses[0], truth[0], "the fixed pose moved");
    }

    #[test]
    fn a_loop_edge_spreads_the_drift_of_biased_odometry() {
        // Biased odometry, one exact loop edge: the drift is spread along the loop, so the
        // worst position error drops well below the dead reckoning's.
        let n = 60;
        let truth: Vec<Se3> = circle(n).iter().map(|p| p.inverse()).collect();
        let (start, steps) = drifted(&truth);
        let mut edges: Vec<PoseGraphEdge> = steps
            .iter()
            .enumerate()
            .map(|(k, s)| edge(k, k + 1, *s))
            .collect();
        edges.push(edge(n - 1, 0, truth[n - 1] * truth[0].inverse()));
        let before = position_error(&start, &truth);
        let mut g = PoseGraph {
            poses: start,
            fixed: vec![false; n],
            edges,
        };
        g.fixed[0] = true;
        let report = optimize_pose_graph(&mut g, 20);
        let after = position_error(&g.poses, &truth);
        eprintln!("worst position error {before:.3} -> {after:.3} m ({report:?})");
        assert!(after < 0.4 * before, "before {before} after {after}");
        assert!(report.final_cost < 0.1 * report.initial_cost, "{report:?}");
    }

    #[test]
    fn a_sim3_loop_edge_undoes_scale_drift() {
        // Monocular odometry whose scale shrinks 1 % a step round a 3 m circle, and one loop
        // edge that knows the true scale at the start. Camera centres are compared after
        // the drifted start is undone by the optimiser.
        let n = 60;
        let truth: Vec<Se3> = circle(n).iter().map(|p| p.inverse()).collect();
        let mut scale = 1.0;
        let mut poses = vec![Sim3::from_rigid(truth[0])];
        let mut edges = Vec::new();
        for k in 1..n {
            // Relative motion k-1 <- k, measured at the scale the map has at k.
            let mut rel = truth[k - 1] * truth[k].inverse();
            rel.translation.vector *= scale;
            let step = Sim3 {
                scale: 1.0,
                rigid: rel,
            };
            // S_k = step⁻¹ ∘ S_(k-1): the drifted chain.
            poses.push(step.inverse().compose(&poses[k - 1]));
            edges.push(Sim3Edge {
                i: k - 1,
                j: k,
                t_ij: step,
                weight: 1.0,
            });
            scale *= 0.99;
        }
        // The loop: camera n-1 seen from camera 0 in the map's units at 0, at the scale
        // the map reached by n-1 (one of its units is `scale` true metres there).
        let loop_rel = truth[0] * truth[n - 1].inverse();
        edges.push(Sim3Edge {
            i: 0,
            j: n - 1,
            t_ij: Sim3 {
                scale: 1.0 / scale,
                rigid: loop_rel,
            },
            weight: 1.0,
        });
        let centres = |ps: &[Sim3]| -> Vec<Vector3<f64>> {
            ps.iter()
                .map(|p| p.inverse().rigid.translation.vector)
                .collect()
        };
        let worst = |ps: &[Sim3]| {
            centres(ps)
                .iter()
                .zip(&truth)
                .map(|(c, t)| (c - t.inverse().translation.vector).norm())
                .fold(0.0, f64::max)
        };
        let before = worst(&poses);
        let mut g = Sim3Graph {
            poses,
            fixed: vec![false; n],
            edges,
        };
        g.fixed[0] = true;
        let report = optimize_sim3_graph(&mut g, 20);
        let after = worst(&g.poses);
        assert!(before > 1.0, "drift {before}");
        assert!(
            after < 0.2 * before,
            "before {before} after {after} ({report:?})"
        );
        // The end of the chain carries the drift as its similarity's scale.
        let s = g.poses[n - 1].scale;
        assert!((s / scale - 1.0).abs() < 0.05, "{s} vs {scale}");
    }

    #[test]
    fn sim3_jacobians_match_a_smaller_step() {
        let a = Sim3 {
            scale: 1.3,
            rigid: Se3::new(Vector3::new(0.3, -0.2, 1.0), Vector3::new(0.1, 0.5, -0.2)),
        };
        let b = Sim3 {
            scale: 0.8,
            rigid: Se3::new(Vector3::new(-0.4, 0.1, 0.2), Vector3::new(-0.3, 0.2, 0.4)),
        };
        let m = Sim3 {
            scale: 1.1,
            rigid: Se3::new(Vector3::new(0.05, 0.0, -0.02), Vector3::new(0.2, -0.1, 0.3)),
        };
        let g = Sim3Graph {
            poses: vec![a, b],
            fixed: vec![false, false],
            edges: vec![Sim3Edge {
                i: 0,
                j: 1,
                t_ij: m,
                weight: 1.0,
            }],
        };
        let (r0, ji, _) = Sim3::linearise(&g, &g.edges[0]);
        for k in 0..7 {
            let mut d = SVector::<f64, 7>::zeros();
            d[k] = 1e-8;
            let mut g2 = g.clone();
            g2.poses[0] = g2.poses[0].retract(&d);
            let (r1, _, _) = Sim3::linearise(&g2, &g2.edges[0]);
            let fd = (r1 - r0) / 1e-8;
            assert!(
                (fd - ji.column(k)).norm() < 1e-4 * (1.0 + fd.norm()),
                "column {k}"
            );
        }
    }

    #[test]
    fn consistent_graph_stays_and_no_fixed_pose_fixes_the_first() {
        let truth: Vec<Se3> = circle(8).iter().map(|p| p.inverse()).collect();
        let edges: Vec<PoseGraphEdge> = (1..8)
            .map(|k| PoseGraphEdge {
                i: k - 1,
                j: k,
                t_ij: truth[k - 1] * truth[k].inverse(),
                weight: 1.0,
            })
            .collect();
        let mut g = PoseGraph {
            poses: truth.clone(),
            fixed: Vec::new(),
            edges,
        };
        let r = optimize_pose_graph(&mut g, 10);
        assert!(r.initial_cost < 1e-20 && position_error(&g.poses, &truth) < 1e-9);
        assert!(g.fixed[0]);
    }

    #[test]
    fn envelope_cholesky_solves_a_banded_system_with_a_far_corner() {
        // 12x12 (two blocks), SPD with coupling between the blocks.
        let dim = 12;
        let mut a = nalgebra::DMatrix::<f64>::zeros(dim, dim);
        for i in 0..dim {
            a[(i, i)] = 4.0 + i as f64;
            if i > 0 {
                a[(i, i - 1)] = 1.0;
                a[(i - 1, i)] = 1.0;
            }
        }
        a[(11, 0)] = 0.5;
        a[(0, 11)] = 0.5;
        let mut env = Envelope::new(dim, 6, &[0, 0]);
        for r in 0..dim {
            for c in 0..=r {
                env.add(r, c, a[(r, c)]);
            }
        }
        let b: Vec<f64> = (0..dim).map(|i| i as f64 - 3.0).collect();
        let x = env.solve(&b).unwrap();
        let ax = &a * nalgebra::DVector::from_vec(x);
        for i in 0..dim {
            assert!((ax[i] - b[i]).abs() < 1e-10);
        }
    }

    #[test]
    fn jacobians_match_finite_differences() {
        let a = Se3::new(Vector3::new(0.3, -0.2, 1.0), Vector3::new(0.1, 0.5, -0.2));
        let b = Se3::new(Vector3::new(-0.4, 0.1, 0.2), Vector3::new(-0.3, 0.2, 0.4));
        let m = Se3::new(Vector3::new(0.05, 0.0, -0.02), Vector3::new(0.2, -0.1, 0.3));
        let e = PoseGraphEdge {
            i: 0,
            j: 1,
            t_ij: m,
            weight: 1.0,
        };
        let g = PoseGraph {
            poses: vec![a, b],
            fixed: vec![false, false],
            edges: vec![e],
        };
        let (r0, ji, jj) = linearise(&g, &e);
        for (v, j) in [(0usize, ji), (1, jj)] {
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = 1e-7;
                let mut g2 = g.clone();
                g2.poses[v] = retract(&g2.poses[v], &d);
                let (r1, _, _) = linearise(&g2, &e);
                let fd = (r1 - r0) / 1e-7;
                assert!(
                    (fd - j.column(k)).norm() < 1e-4 * (1.0 + fd.norm()),
                    "vertex {v} column {k}: {fd} vs {}",
                    j.column(k)
                );
            }
        }
    }
}
