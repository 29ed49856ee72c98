//! Keypoints near an epipolar line, found through a grid instead of testing every keypoint.
//!
//! Local mapping matches each free keypoint of a new keyframe along its epipolar line in each
//! neighbour (ORB-SLAM3 `SearchForTriangulation`). Tested against every free keypoint of each
//! of a monocular keyframe's 30 neighbours, where nearly every keypoint is free, that was over a
//! third of a monocular run. The grid visits only the cells the line's band crosses and hands
//! each keypoint there to the caller's exact test, which is unchanged; the visits come in no
//! order, so a caller that breaks ties by order does so by index.

/// Points bucketed into square cells, each stored with the caller's item (its index and what
/// its test needs), so that a line's candidates are read in runs of memory.
pub struct EpipolarGrid<T> {
    min_x: f64,
    min_y: f64,
    cell: f64,
    cols: usize,
    rows: usize,
    /// The items by cell, the cells row after row (a row of cells is one run).
    by_rows: Bucketed<T>,
    /// The same, column after column.
    by_cols: Bucketed<T>,
    /// The items at no finite point (in no cell), visited with the cells' for a line that
    /// is not finite.
    unplaced: Vec<T>,
    /// Largest distance from a line that a caller's test can accept, in pixels, with a margin.
    reach: f64,
}

/// Items ordered by cell; `starts[c]..starts[c + 1]` are cell c's.
struct Bucketed<T> {
    items: Vec<T>,
    starts: Vec<usize>,
}

impl<T: Copy> Bucketed<T> {
    /// Counting sort of the items by cell (stable: in the caller's order within a cell).
    fn new(all: &[T], cells: &[Option<usize>], count: usize) -> Self {
        let mut starts = vec![0; count + 1];
        for c in cells.iter().flatten() {
            starts[c + 1] += 1;
        }
        for c in 0..count {
            starts[c + 1] += starts[c];
        }
        let mut slots: Vec<Option<T>> = vec![None; starts[count]];
        let mut next = starts.clone();
        for (item, c) in all.iter().zip(cells) {
            if let Some(c) = *c {
                slots[next[c]] = Some(*item);
                next[c] += 1;
            }
        }
        Bucketed {
            items: slots.into_iter().flatten().collect(),
            starts,
        }
    }

    /// The items of cells `first..=last`.
    fn run(&self, first: usize, last: usize) -> &[T] {
        &self.items[self.starts[first]..self.starts[last + 1]]
    }
}

impl<T: Copy> EpipolarGrid<T> {
    /// A grid over `items`, each at the image point `at(item)`, with cells of `cell` pixels;
    /// `max_distance` is the largest distance from a line (in pixels) the caller will accept
    /// for any item.
    pub fn new(items: &[T], at: impl Fn(&T) -> (f64, f64), cell: f64, max_distance: f64) -> Self {
        let points: Vec<(f64, f64)> = items.iter().map(&at).collect();
        let finite = |&(x, y): &(f64, f64)| x.is_finite() && y.is_finite();
        let (mut min_x, mut max_x, mut min_y, mut max_y) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (k, &(x, y)) in points.iter().filter(|p| finite(p)).enumerate() {
            if k == 0 {
                (min_x, max_x, min_y, max_y) = (x, x, y, y);
            } else {
                min_x = min_x.min(x);
                max_x = max_x.max(x);
                min_y = min_y.min(y);
                max_y = max_y.max(y);
            }
        }
        let cell = if cell.is_finite() && cell > 0.0 {
            cell
        } else {
            32.0
        };
        // At most 4096 cells a side: coordinates far apart (a bad keypoint) must not make the
        // grid huge; a coarser grid only costs speed.
        let cell = cell.max((max_x - min_x).max(max_y - min_y) / 4096.0);
        let cols = ((max_x - min_x) / cell) as usize + 1;
        let rows = ((max_y - min_y) / cell) as usize + 1;
        let at_cell = |v: f64, min: f64, count: usize| (((v - min) / cell) as usize).min(count - 1);
        let cells: Vec<Option<(usize, usize)>> = points
            .iter()
            .map(|p| finite(p).then(|| (at_cell(p.0, min_x, cols), at_cell(p.1, min_y, rows))))
            .collect();
        let row_major: Vec<Option<usize>> = cells
            .iter()
            .map(|c| c.map(|(col, row)| row * cols + col))
            .collect();
        let col_major: Vec<Option<usize>> = cells
            .iter()
            .map(|c| c.map(|(col, row)| col * rows + row))
            .collect();
        let unplaced = items
            .iter()
            .zip(&cells)
            .filter(|(_, c)| c.is_none())
            .map(|(item, _)| *item)
            .collect();
        EpipolarGrid {
            min_x,
            min_y,
            cell,
            cols,
            rows,
            by_rows: Bucketed::new(items, &row_major, cols * rows),
            by_cols: Bucketed::new(items, &col_major, cols * rows),
            unplaced,
            reach: max_distance.abs() * (1.0 + 1e-6) + 0.5,
        }
    }

    /// Calls `visit` with every item that may lie within the grid's distance of the line
    /// `a x + b y + c = 0`, each once, in no particular order. Every item is visited when
    /// the line is not finite, so a caller's exact test decides as it would without the grid.
    pub fn near_line(&self, a: f64, b: f64, c: f64, mut visit: impl FnMut(&T)) {
        let norm = (a * a + b * b).sqrt();
        if !(a.is_finite() && b.is_finite() && c.is_finite() && norm > 0.0 && norm.is_finite()) {
            self.by_rows
                .items
                .iter()
                .chain(&self.unplaced)
                .for_each(visit);
            return;
        }
        // Walk along the line's long axis: per column (or row) of cells, the span of the other
        // coordinate the band covers there, one run of cells.
        let horizontal = b.abs() >= a.abs();
        let (along_coef, across_coef, start_along, start_across, count_along, count_across, cells) =
            if horizontal {
                (
                    a,
                    b,
                    self.min_x,
                    self.min_y,
                    self.cols,
                    self.rows,
                    &self.by_cols,
                )
            } else {
                (
                    b,
                    a,
                    self.min_y,
                    self.min_x,
                    self.rows,
                    self.cols,
                    &self.by_rows,
                )
            };
        // The across-coordinate of the line, in cells from the grid's edge, at the start of
        // each step along it; the margin in `reach` covers the rounding of the steps.
        let inv_cell = 1.0 / self.cell;
        let half = self.reach * norm / across_coef.abs() * inv_cell;
        let v_start = (-(along_coef * start_along + c) / across_coef - start_across) * inv_cell;
        let step = -along_coef / across_coef;
        let last_cell = count_across as f64;
        for k in 0..count_along {
            let v0 = v_start + k as f64 * step;
            let v1 = v0 + step;
            let first = v0.min(v1) - half;
            let last = v0.max(v1) + half;
            if last < 0.0 || first >= last_cell {
                continue;
            }
            let first = first.max(0.0) as usize;
            let last = (last as usize).min(count_across - 1);
            let base = k * count_across;
            cells
                .run(base + first, base + last)
                .iter()
                .for_each(&mut visit);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (no dependency for a test).
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    fn brute(xs: &[f64], ys: &[f64], a: f64, b: f64, c: f64, d: f64) -> Vec<usize> {
        let n2 = a * a + b * b;
        (0..xs.len())
            .filter(|&n| {
                let e = a * xs[n] + b * ys[n] + c;
                e * e / n2 < d * d
            })
            .collect()
    }

    #[test]
    fn every_point_near_a_line_is_handed_back_in_order() {
        let mut r = Lcg(7);
        let xs: Vec<f64> = (0..2000).map(|_| r.next() * 640.0).collect();
        let ys: Vec<f64> = (0..2000).map(|_| r.next() * 480.0).collect();
        let grid = EpipolarGrid::new(&Vec::from_iter(0..xs.len()), |&n| (xs[n], ys[n]), 24.0, 7.0);
        let mut out = Vec::new();
        let mut handed_back = 0;
        for _ in 0..2000 {
            // Lines of every slope, some through the image, some beside it.
            let angle = r.next() * std::f64::consts::PI;
            let (a, b) = (angle.cos(), angle.sin());
            let (px, py) = (r.next() * 900.0 - 130.0, r.next() * 700.0 - 110.0);
            let scale = 1e-4 + r.next() * 3.0;
            let (a, b, c) = (a * scale, b * scale, -(a * px + b * py) * scale);
            let d = 0.5 + r.next() * 6.5;
            out.clear();
            grid.near_line(a, b, c, |&n| out.push(n));
            out.sort_unstable();
            assert!(out.windows(2).all(|w| w[0] < w[1]), "each point once");
            let want = brute(&xs, &ys, a, b, c, d);
            let kept: Vec<usize> = out
                .iter()
                .copied()
                .filter(|&n| want.binary_search(&n).is_ok())
                .collect();
            assert_eq!(kept, want);
            handed_back += out.len();
        }
        // The point of the grid: a small share of the points per line.
        assert!(handed_back < 2000 * 2000 / 4, "{handed_back}");
    }

    #[test]
    fn axis_lines_and_bad_input_fall_back_to_every_point() {
        let xs = [0.0, 10.0, 20.0, f64::NAN, 5.0];
        let ys = [0.0, 10.0, 20.0, 3.0, f64::INFINITY];
        let grid = EpipolarGrid::new(&Vec::from_iter(0..xs.len()), |&n| (xs[n], ys[n]), 4.0, 1.0);
        let mut out = Vec::new();
        let near = |a: f64, b: f64, c: f64, out: &mut Vec<usize>| {
            out.clear();
            grid.near_line(a, b, c, |&n| out.push(n));
            out.sort_unstable();
        };
        // x = 10: exactly vertical.
        near(1.0, 0.0, -10.0, &mut out);
        assert!(out.contains(&1));
        // y = 20: exactly horizontal.
        near(0.0, 1.0, -20.0, &mut out);
        assert!(out.contains(&2));
        near(f64::NAN, 1.0, 0.0, &mut out);
        assert_eq!(out, vec![0, 1, 2, 3, 4]);
        near(0.0, 0.0, 1.0, &mut out);
        assert_eq!(out.len(), 5);
        let empty = EpipolarGrid::<usize>::new(&[], |_| (0.0, 0.0), 16.0, 3.0);
        let mut visited = 0;
        empty.near_line(1.0, 1.0, 1.0, |_| visited += 1);
        assert_eq!(visited, 0);
    }
}
