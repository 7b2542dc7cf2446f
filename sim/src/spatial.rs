//! A uniform grid over a bounded region: which boxes might touch which. Each box is
//! registered in every cell its axis-aligned bounds cover; a query returns the ids found in
//! the cells it covers, sorted and without repeats, so results never depend on insertion
//! order within a cell.

use maps::Point;
use maps::geometry::Bounds;

#[derive(Debug, Clone)]
pub struct UniformGrid {
    origin: Point,
    cell_m: f64,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<u32>>,
}

impl UniformGrid {
    /// A grid over `bounds` with square cells of `cell_m` metres; positions outside the
    /// bounds fall into the border cells.
    pub fn new(bounds: Bounds, cell_m: f64) -> Self {
        let cell_m = if cell_m.is_finite() && cell_m > 0.0 {
            cell_m
        } else {
            10.0
        };
        let (origin, w, h) =
            if bounds.is_empty() || !bounds.min.is_finite() || !bounds.max.is_finite() {
                (Point::default(), 1.0, 1.0)
            } else {
                (bounds.min, bounds.width(), bounds.height())
            };
        let cols = ((w / cell_m).ceil() as usize).clamp(1, 4096);
        let rows = ((h / cell_m).ceil() as usize).clamp(1, 4096);
        UniformGrid {
            origin,
            cell_m,
            cols,
            rows,
            cells: vec![Vec::new(); cols * rows],
        }
    }

    pub fn clear(&mut self) {
        self.cells.iter_mut().for_each(Vec::clear);
    }

    fn cell_range(&self, lo: Point, hi: Point) -> (usize, usize, usize, usize) {
        let col = |x: f64| {
            (((x - self.origin.x) / self.cell_m).floor().max(0.0) as usize).min(self.cols - 1)
        };
        let row = |y: f64| {
            (((y - self.origin.y) / self.cell_m).floor().max(0.0) as usize).min(self.rows - 1)
        };
        (col(lo.x), col(hi.x), row(lo.y), row(hi.y))
    }

    /// Registers `id` in the cells covered by the box `lo`..`hi`.
    pub fn insert(&mut self, id: u32, lo: Point, hi: Point) {
        let (c0, c1, r0, r1) = self.cell_range(lo, hi);
        for r in r0..=r1 {
            for c in c0..=c1 {
                self.cells[r * self.cols + c].push(id);
            }
        }
    }

    /// Ids registered in the cells covered by `lo`..`hi`, sorted, each once.
    pub fn query(&self, lo: Point, hi: Point, out: &mut Vec<u32>) {
        out.clear();
        let (c0, c1, r0, r1) = self.cell_range(lo, hi);
        for r in r0..=r1 {
            for c in c0..=c1 {
                out.extend_from_slice(&self.cells[r * self.cols + c]);
            }
        }
        out.sort_unstable();
        out.dedup();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_neighbours_and_not_far_boxes() {
        let mut b = Bounds::empty();
        b.extend(Point::new(0.0, 0.0));
        b.extend(Point::new(100.0, 100.0));
        let mut g = UniformGrid::new(b, 10.0);
        g.insert(1, Point::new(5.0, 5.0), Point::new(12.0, 8.0));
        g.insert(2, Point::new(80.0, 80.0), Point::new(84.0, 82.0));
        g.insert(3, Point::new(-50.0, 5.0), Point::new(-45.0, 8.0));
        let mut out = Vec::new();
        g.query(Point::new(11.0, 6.0), Point::new(13.0, 7.0), &mut out);
        assert_eq!(out, vec![1]);
        g.query(Point::new(-1.0, 0.0), Point::new(15.0, 9.0), &mut out);
        assert_eq!(out, vec![1, 3]);
        g.clear();
        g.query(Point::new(0.0, 0.0), Point::new(100.0, 100.0), &mut out);
        assert!(out.is_empty());
    }
}
