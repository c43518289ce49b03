//! [`RadianceGrid`]: the reflected radiance `L_r(x, ω_o)` that Russian roulette and splitting
//! weigh a path by, learned as cell means of the renderer's own path estimates.
//!
//! The recorders give, for every vertex whose path went on, the one-sample estimate
//! `L̃_r = D + β L̃_i` of the light it reflects towards the previous vertex
//! ([`crate::recorder`]). The grid averages them over cells of space × the orientation of the
//! shading normal (the dominant axis and its sign, six bins, and a seventh for vertices
//! without a normal): two sides of a wall fall into different bins, so the lit side of a
//! door's wall does not raise the estimate of its dark side. The estimate ignores `ω_o`
//! (diffuse-like), as ADRRS's spatial cache does between its directional bins.
//!
//! Three levels answer a lookup, each shrunk towards the one above it: with `k` =
//! [`GridOptions::prior_weight`], `S` and `n` a cell's sum and count,
//!
//! `L̂_global = S_g / n_g`, `L̂_coarse = (S_c + k L̂_global) / (n_c + k)`,
//! `L̂_fine = (S_f + k L̂_coarse) / (n_f + k)`
//!
//! (the fine grid has `resolution` cells along the scene's longest side, the coarse one
//! `coarse_resolution`): a cell with few estimates answers near its parent, one with many its
//! own mean. Without shrinkage a dark-looking cell whose few estimates were all 0 would answer
//! 0, and the window would roulette every path through it at its least survival probability,
//! though one path in a hundred finds the light there. The estimate only moves work between
//! paths; the image's expectation never depends on it. Only an empty grid answers nothing
//! (the window then leaves the path alone).
//!
//! Why a grid and not the guide: the vMF / NASG / DF guides are normalised distributions of
//! direction (their integral is 1, not the radiance), and `pt` / `pt-nee` have no guide at
//! all, while every method can record its paths. The DF representation's radiance cache could
//! answer too; it is not wired here.

use super::luminance;
use crate::recorder::ReflectedSample;
use crate::GuidingError;

/// Options of a [`RadianceGrid`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GridOptions {
    /// Fine cells along the scene's longest side (`≥ 1`).
    pub resolution: u32,
    /// Coarse cells along the longest side (`≥ 1`), the fallback of sparse fine cells.
    pub coarse_resolution: u32,
    /// `k`: how many estimates a cell's own mean needs to weigh as much as its parent's
    /// (`≥ 1`).
    pub prior_weight: u32,
}

impl Default for GridOptions {
    /// 32 fine and 8 coarse cells along the longest side (at most 32³ × 7 cells of 32 bytes,
    /// 7 MiB); `k = 16` (a cell's own mean then has a quarter of one estimate's standard
    /// deviation when it weighs as much as its parent).
    fn default() -> Self {
        Self {
            resolution: 32,
            coarse_resolution: 8,
            prior_weight: 16,
        }
    }
}

/// Orientation bins: ±x, ±y, ±z and "no normal".
const BINS: usize = 7;

/// Running sums of one cell.
#[derive(Clone, Copy, Debug, Default)]
struct Cell {
    sum: [f64; 3],
    /// Sums of squares (the second moment).
    sum2: [f64; 3],
    count: u32,
}

/// One level of the grid.
#[derive(Clone, Debug)]
struct Level {
    dims: [u32; 3],
    inv_cell: f32,
    cells: Vec<Cell>,
}

impl Level {
    fn new(extent: [f32; 3], resolution: u32) -> Self {
        let longest = extent[0].max(extent[1]).max(extent[2]);
        let cell = if longest > 0.0 {
            longest / resolution as f32
        } else {
            1.0
        };
        let dims = [0, 1, 2].map(|a| ((extent[a] / cell).ceil() as u32).clamp(1, resolution));
        let n = dims.iter().map(|&d| d as usize).product::<usize>() * BINS;
        Self {
            dims,
            inv_cell: 1.0 / cell,
            cells: vec![Cell::default(); n],
        }
    }

    fn index(&self, local: [f32; 3], bin: usize) -> usize {
        let mut idx = 0usize;
        for a in (0..3).rev() {
            let c = ((local[a] * self.inv_cell) as i64).clamp(0, i64::from(self.dims[a]) - 1);
            idx = idx * self.dims[a] as usize + c as usize;
        }
        idx * BINS + bin
    }
}

/// Spatial cell means of reflected radiance; see the [module docs](self).
#[derive(Clone, Debug)]
pub struct RadianceGrid {
    min: [f32; 3],
    options: GridOptions,
    fine: Level,
    coarse: Level,
    global: Cell,
    samples: u64,
    rejected: u64,
}

/// What a [`RadianceGrid`] holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GridStats {
    /// Estimates added.
    pub samples: u64,
    /// Estimates refused (a non-finite position, a negative or non-finite radiance).
    pub rejected: u64,
    /// Fine cells (× orientation bins) with at least `prior_weight` estimates (their own
    /// mean weighs at least as much as their parent's).
    pub fine_cells: u64,
    /// Coarse cells with at least `prior_weight` estimates.
    pub coarse_cells: u64,
}

/// The orientation bin of a shading normal.
fn bin(normal: [f32; 3]) -> usize {
    let abs = normal.map(f32::abs);
    if !(abs.iter().all(|x| x.is_finite())) || abs == [0.0; 3] {
        return BINS - 1;
    }
    let axis = if abs[0] >= abs[1] && abs[0] >= abs[2] {
        0
    } else if abs[1] >= abs[2] {
        1
    } else {
        2
    };
    2 * axis + usize::from(normal[axis] < 0.0)
}

impl RadianceGrid {
    /// An empty grid over the box `[min, max]` (the scene's bounds; positions outside fall
    /// into the nearest cell).
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] for a box with a non-finite or inverted corner, or an
    /// option of 0.
    pub fn new(min: [f32; 3], max: [f32; 3], options: GridOptions) -> Result<Self, GuidingError> {
        if !(0..3).all(|a| min[a].is_finite() && max[a].is_finite() && min[a] <= max[a]) {
            return Err(GuidingError::InvalidConfig(format!(
                "radiance grid box {min:?} – {max:?} must be finite with min <= max"
            )));
        }
        if options.resolution == 0 || options.coarse_resolution == 0 || options.prior_weight == 0 {
            return Err(GuidingError::InvalidConfig(format!(
                "radiance grid options {options:?}: every option must be at least 1"
            )));
        }
        let extent = [0, 1, 2].map(|a| max[a] - min[a]);
        Ok(Self {
            min,
            options,
            fine: Level::new(extent, options.resolution),
            coarse: Level::new(extent, options.coarse_resolution),
            global: Cell::default(),
            samples: 0,
            rejected: 0,
        })
    }

    /// The options it was made with.
    #[must_use]
    pub fn options(&self) -> &GridOptions {
        &self.options
    }

    fn local(&self, p: [f32; 3]) -> Option<[f32; 3]> {
        p.iter()
            .all(|x| x.is_finite())
            .then(|| [0, 1, 2].map(|a| p[a] - self.min[a]))
    }

    /// Adds one estimate `radiance` of the light reflected at `position` (shading normal
    /// `normal`, zero if unknown); returns whether it was kept (refused: a non-finite
    /// position, a negative or non-finite radiance).
    pub fn add(&mut self, position: [f32; 3], normal: [f32; 3], radiance: [f32; 3]) -> bool {
        let ok = radiance.iter().all(|x| x.is_finite() && *x >= 0.0);
        let Some(local) = self.local(position).filter(|_| ok) else {
            self.rejected += 1;
            return false;
        };
        let b = bin(normal);
        let fine = self.fine.index(local, b);
        let coarse = self.coarse.index(local, b);
        for cell in [
            &mut self.fine.cells[fine],
            &mut self.coarse.cells[coarse],
            &mut self.global,
        ] {
            for (c, r) in radiance.into_iter().enumerate() {
                let r = f64::from(r);
                cell.sum[c] += r;
                cell.sum2[c] += r * r;
            }
            cell.count = cell.count.saturating_add(1);
        }
        self.samples += 1;
        true
    }

    /// [`Self::add`] for every recorded sample.
    pub fn add_samples(&mut self, samples: &[ReflectedSample]) {
        for s in samples {
            self.add(s.position, s.normal, s.radiance);
        }
    }

    /// The reflected radiance at `position` (normal `normal`): the fine cell's mean shrunk
    /// towards the coarse cell's, shrunk towards the global mean (see the [module
    /// docs](self)); `None` for an empty grid or a non-finite position.
    #[must_use]
    pub fn estimate(&self, position: [f32; 3], normal: [f32; 3]) -> Option<[f32; 3]> {
        self.shrunk(position, normal, |c| c.sum)
    }

    /// The second moment `E[L_r²]` per channel at `position`, shrunk across the levels as
    /// [`Self::estimate`] (what [`super::WeightWindow::efficiency_continuations`] weighs).
    #[must_use]
    pub fn second_moment(&self, position: [f32; 3], normal: [f32; 3]) -> Option<[f32; 3]> {
        self.shrunk(position, normal, |c| c.sum2)
    }

    /// The shrunk mean of the per-cell sums `sums` (see the [module docs](self)).
    fn shrunk(
        &self,
        position: [f32; 3],
        normal: [f32; 3],
        sums: impl Fn(&Cell) -> [f64; 3],
    ) -> Option<[f32; 3]> {
        let local = self.local(position)?;
        if self.global.count == 0 {
            return None;
        }
        let b = bin(normal);
        let k = f64::from(self.options.prior_weight);
        let shrink = |cell: &Cell, prior: [f64; 3]| {
            let (s, n) = (sums(cell), f64::from(cell.count) + k);
            [0, 1, 2].map(|c| (s[c] + k * prior[c]) / n)
        };
        let n = f64::from(self.global.count);
        let global = sums(&self.global).map(|s| s / n);
        let coarse = shrink(&self.coarse.cells[self.coarse.index(local, b)], global);
        let fine = shrink(&self.fine.cells[self.fine.index(local, b)], coarse);
        Some(fine.map(|x| x as f32))
    }

    /// [`Self::estimate`] for every row, a missing one written as `[-1, -1, -1]` (what
    /// [`super::WeightWindow::continuations`] reads as missing).
    ///
    /// # Errors
    /// [`GuidingError::LengthMismatch`] if the slices differ in length; `out` is untouched.
    pub fn estimate_batch(
        &self,
        positions: &[[f32; 3]],
        normals: &[[f32; 3]],
        out: &mut Vec<[f32; 3]>,
    ) -> Result<(), GuidingError> {
        if positions.len() != normals.len() {
            return Err(GuidingError::LengthMismatch {
                what: format!("{} positions, {} normals", positions.len(), normals.len()),
            });
        }
        out.clear();
        out.extend(
            positions
                .iter()
                .zip(normals)
                .map(|(p, n)| self.estimate(*p, *n).unwrap_or([-1.0; 3])),
        );
        Ok(())
    }

    /// The luminance of [`Self::estimate`], `None` where it has none.
    #[must_use]
    pub fn estimate_luminance(&self, position: [f32; 3], normal: [f32; 3]) -> Option<f32> {
        self.estimate(position, normal).map(luminance)
    }

    /// What it holds.
    #[must_use]
    pub fn stats(&self) -> GridStats {
        let answering = |level: &Level| {
            level
                .cells
                .iter()
                .filter(|c| c.count >= self.options.prior_weight)
                .count() as u64
        };
        GridStats {
            samples: self.samples,
            rejected: self.rejected,
            fine_cells: answering(&self.fine),
            coarse_cells: answering(&self.coarse),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(prior_weight: u32) -> RadianceGrid {
        RadianceGrid::new(
            [0.0; 3],
            [4.0, 2.0, 1.0],
            GridOptions {
                resolution: 4,
                coarse_resolution: 1,
                prior_weight,
            },
        )
        .unwrap()
    }

    fn close(a: Option<[f32; 3]>, b: [f32; 3]) -> bool {
        a.is_some_and(|a| (0..3).all(|c| (a[c] - b[c]).abs() <= 1e-5 * b[c].abs().max(1.0)))
    }

    /// The shrinkage written out: global mean, coarse cell towards it, fine cell towards
    /// the coarse answer, each with `k` pseudo-estimates.
    #[test]
    fn cells_shrink_towards_their_parents() {
        let mut g = grid(2);
        let (up, down) = ([0.0, 0.0, 1.0], [0.0, 0.0, -1.0]);
        assert_eq!(g.estimate([0.5, 0.5, 0.5], up), None);
        assert!(g.add([0.5, 0.5, 0.5], up, [1.0, 2.0, 3.0]));
        assert!(g.add([0.9, 0.1, 0.2], up, [3.0, 2.0, 1.0]));
        // One cell, one bin so far: every level's mean is (2, 2, 2).
        assert!(close(g.estimate([0.5, 0.5, 0.5], up), [2.0; 3]));
        g.add([3.5, 1.5, 0.5], down, [8.0; 3]);
        g.add([3.6, 1.6, 0.6], down, [8.0; 3]);
        // Global mean 5. Coarse (up) = (4 + 2·5)/(2 + 2) = 3.5; fine (0,0,0) up =
        // (4 + 2·3.5)/4 = 2.75; an empty fine cell (up) answers the coarse 3.5.
        assert!(close(g.estimate([0.5, 0.5, 0.5], up), [2.75; 3]));
        assert!(close(g.estimate([1.5, 0.5, 0.5], up), [3.5; 3]));
        // Coarse (down) = (16 + 10)/4 = 6.5; fine (3,1,0) down = (16 + 13)/4 = 7.25.
        assert!(close(g.estimate([3.5, 1.5, 0.5], down), [7.25; 3]));
        // A bin never seen: the global mean through two empty levels.
        assert!(close(
            g.estimate([3.5, 1.5, 0.5], [1.0, 0.0, 0.0]),
            [5.0; 3]
        ));
        let s = g.stats();
        assert_eq!(
            (s.samples, s.rejected, s.fine_cells, s.coarse_cells),
            (4, 0, 2, 2)
        );
        // Second moments the same way: global (1+9+64+64, 4+4+64+64, 9+1+64+64)/4; the
        // fine (3,1,0) down cell (128 + 2·coarse)/4 with coarse (128 + 2·global)/4.
        let global = [138.0 / 4.0, 136.0 / 4.0, 138.0 / 4.0];
        let coarse = global.map(|g: f32| (128.0 + 2.0 * g) / 4.0);
        let fine = coarse.map(|c| (128.0 + 2.0 * c) / 4.0);
        assert!(close(g.second_moment([3.5, 1.5, 0.5], down), fine));
    }

    /// The two sides of a wall (opposite normals) and vertices without a normal are kept
    /// apart: with many estimates on each side, each side answers its own mean.
    #[test]
    fn orientations_are_kept_apart() {
        let mut g = grid(1);
        let p = [2.0, 1.0, 0.5];
        for _ in 0..1000 {
            g.add(p, [1.0, 0.0, 0.0], [4.0; 3]);
            g.add(p, [-1.0, 0.1, 0.0], [0.5; 3]);
        }
        let near = |e: Option<[f32; 3]>, v: f32| e.is_some_and(|e| (e[0] - v).abs() < 0.01);
        assert!(near(g.estimate(p, [0.9, 0.3, 0.0]), 4.0));
        assert!(near(g.estimate(p, [-0.9, 0.3, 0.0]), 0.5));
        // No normal, or an orientation never seen: the global mean.
        assert!(near(g.estimate(p, [0.0; 3]), 2.25));
        assert!(near(g.estimate(p, [0.0, 0.0, 1.0]), 2.25));
    }

    #[test]
    fn bad_input_is_refused_and_outside_points_clamp() {
        let mut g = grid(1);
        let up = [0.0, 0.0, 1.0];
        for bad in [[f32::NAN, 0.0, 0.0], [-1.0, 0.0, 0.0], [f32::INFINITY; 3]] {
            assert!(!g.add([1.0; 3], up, bad));
        }
        assert!(!g.add([f32::NAN, 0.0, 0.0], up, [1.0; 3]));
        assert_eq!(g.stats().rejected, 4);
        assert_eq!(g.estimate([1.0; 3], up), None);
        let mut out = Vec::new();
        g.estimate_batch(&[[0.1; 3]], &[up], &mut out).unwrap();
        assert_eq!(out, [[-1.0; 3]]);
        // Far outside the box: the nearest (corner) cell.
        assert!(g.add([-100.0, -5.0, -5.0], up, [2.0; 3]));
        assert!(g.add([3.9, 1.9, 0.9], up, [6.0; 3]));
        // Corner fine cell: (2 + 1·4)/2 = 3 with the coarse (8 + 4)/3 = 4 and global 4.
        assert!(close(g.estimate([0.1, 0.1, 0.1], up), [3.0; 3]));
        assert_eq!(g.estimate([f32::NAN; 3], up), None);
        g.estimate_batch(&[[0.1; 3], [f32::NAN; 3]], &[up, up], &mut out)
            .unwrap();
        assert!(close(Some(out[0]), [3.0; 3]) && out[1] == [-1.0; 3]);
        assert!(g.estimate_batch(&[[0.1; 3]], &[], &mut out).is_err());
        assert_eq!(out.len(), 2);
    }

    #[test]
    fn bad_boxes_and_options_are_refused() {
        let o = GridOptions::default();
        assert!(RadianceGrid::new([0.0; 3], [f32::NAN; 3], o).is_err());
        assert!(RadianceGrid::new([1.0; 3], [0.0; 3], o).is_err());
        for bad in [
            GridOptions { resolution: 0, ..o },
            GridOptions {
                coarse_resolution: 0,
                ..o
            },
            GridOptions {
                prior_weight: 0,
                ..o
            },
        ] {
            assert!(RadianceGrid::new([0.0; 3], [1.0; 3], bad).is_err());
        }
        // A flat (degenerate) box is a grid of one layer.
        let g = RadianceGrid::new([0.0; 3], [1.0, 1.0, 0.0], o).unwrap();
        assert_eq!(g.fine.dims, [32, 32, 1]);
        let point = RadianceGrid::new([1.0; 3], [1.0; 3], o).unwrap();
        assert_eq!(point.fine.dims, [1, 1, 1]);
    }
}
