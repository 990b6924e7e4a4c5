//! Uniform-grid neighbour search: one step costs O(N) at fixed density instead of O(N^2).
//!
//! Cells are at least the query radius wide, so every neighbour of an agent lies in the 3x3
//! block of cells around it. Agents are bucketed by a counting sort that keeps slot order inside
//! each cell, so the order in which neighbours are visited is a pure function of the state.

use crate::geometry::Vec2;

#[derive(Debug, Default, Clone)]
pub struct Grid {
    origin: Vec2,
    cell: f64,
    nx: usize,
    ny: usize,
    cell_of: Vec<u32>,
    /// Column and row of each agent's cell (`cell_of` without a division per query).
    cell_xy: Vec<(u32, u32)>,
    /// `starts[c]..starts[c + 1]` indexes `sorted` for cell `c`.
    starts: Vec<u32>,
    sorted: Vec<u32>,
    /// Positions in `sorted` order (structure of arrays): the candidates of one row of cells are
    /// contiguous, so their distance test is a vectorisable loop.
    sorted_x: Vec<f64>,
    sorted_y: Vec<f64>,
    /// Scratch of the counting sort.
    fill: Vec<u32>,
}

impl Grid {
    /// Rebuilds the grid over `positions` for queries of radius `radius` (all inputs finite).
    pub fn rebuild(&mut self, positions: &[Vec2], radius: f64) {
        let n = positions.len();
        self.cell_of.clear();
        self.cell_xy.clear();
        self.sorted.clear();
        self.sorted_x.clear();
        self.sorted_y.clear();
        if n == 0 {
            self.nx = 0;
            self.ny = 0;
            self.starts.clear();
            self.starts.push(0);
            return;
        }
        let (mut lo, mut hi) = (positions[0], positions[0]);
        for p in positions {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        let extent = hi - lo;
        // Cells no narrower than the radius; widened when the agents are so sparse that the grid
        // would have far more cells than agents (memory stays O(N)).
        let mut cell = radius.max(1e-9);
        let max_cells = (4 * n + 64) as f64;
        // `floor` of these non-negative quotients by truncation (`floor` is a libm call on the
        // baseline x86_64 target); past 2^64 both only compare above `max_cells`.
        let whole = |q: f64| (q as u64) as f64;
        let cells_for = |c: f64| (whole(extent.x / c) + 1.0) * (whole(extent.y / c) + 1.0);
        while cells_for(cell) > max_cells {
            cell *= 2.0;
        }
        self.origin = lo;
        self.cell = cell;
        self.nx = (extent.x / cell) as usize + 1;
        self.ny = (extent.y / cell) as usize + 1;
        let ncell = self.nx * self.ny;
        if ncell == 1 {
            // One cell (every scene smaller than the radius): the counting sort below would
            // keep slot order, so the sorted order is the identity.
            self.starts.clear();
            self.starts.extend_from_slice(&[0, n as u32]);
            self.cell_of.resize(n, 0);
            self.cell_xy.resize(n, (0, 0));
            self.sorted.extend(0..n as u32);
            self.sorted_x.extend(positions.iter().map(|p| p.x));
            self.sorted_y.extend(positions.iter().map(|p| p.y));
            return;
        }
        self.starts.clear();
        self.starts.resize(ncell + 1, 0);
        for p in positions {
            let (cx, cy) = self.cell_coords(*p);
            let c = cy * self.nx + cx;
            self.cell_of.push(c as u32);
            self.cell_xy.push((cx as u32, cy as u32));
            self.starts[c + 1] += 1;
        }
        for c in 0..ncell {
            self.starts[c + 1] += self.starts[c];
        }
        self.sorted.resize(n, 0);
        self.sorted_x.resize(n, 0.0);
        self.sorted_y.resize(n, 0.0);
        self.fill.clear();
        self.fill.extend_from_slice(&self.starts[..ncell]);
        for (i, (&c, p)) in self.cell_of.iter().zip(positions).enumerate() {
            let slot = &mut self.fill[c as usize];
            let k = *slot as usize;
            self.sorted[k] = i as u32;
            self.sorted_x[k] = p.x;
            self.sorted_y[k] = p.y;
            *slot += 1;
        }
    }

    /// Agent slots in cell order, and their positions (`x`, `y`) in the same order.
    #[inline]
    pub(crate) fn sorted(&self) -> (&[u32], &[f64], &[f64]) {
        (&self.sorted, &self.sorted_x, &self.sorted_y)
    }

    /// The ranges of [`Grid::sorted`] that hold the candidates of agent `i` (the 3x3 block of
    /// cells around it, one range per row of cells, in the order [`Grid::for_each_candidate`]
    /// visits them). Returns the ranges and how many of the three are used.
    #[inline]
    pub(crate) fn candidate_ranges(&self, i: usize) -> ([(usize, usize); 3], usize) {
        let (cx, cy) = self.cell_xy[i];
        let (cx, cy) = (cx as usize, cy as usize);
        let y0 = cy.saturating_sub(1);
        let y1 = (cy + 1).min(self.ny - 1);
        let x0 = cx.saturating_sub(1);
        let x1 = (cx + 1).min(self.nx - 1);
        let mut out = [(0, 0); 3];
        for (k, y) in (y0..=y1).enumerate() {
            // Cells x0..=x1 of one row are contiguous in `sorted`.
            out[k] = (
                self.starts[y * self.nx + x0] as usize,
                self.starts[y * self.nx + x1 + 1] as usize,
            );
        }
        (out, y1 - y0 + 1)
    }

    fn cell_coords(&self, p: Vec2) -> (usize, usize) {
        // Truncating the clamped quotient is its floor (and NaN gives 0 either way).
        let cx = ((((p.x - self.origin.x) / self.cell).max(0.0)) as usize).min(self.nx - 1);
        let cy = ((((p.y - self.origin.y) / self.cell).max(0.0)) as usize).min(self.ny - 1);
        (cx, cy)
    }

    /// Calls `f(j)` for every agent slot `j` in the 3x3 block of cells around agent `i` (a
    /// superset of its neighbours within the radius, `i` itself included).
    #[inline]
    pub fn for_each_candidate(&self, i: usize, mut f: impl FnMut(usize)) {
        let (ranges, rows) = self.candidate_ranges(i);
        for &(a, b) in &ranges[..rows] {
            for &j in &self.sorted[a..b] {
                f(j as usize);
            }
        }
    }
}
