//! A sum tree: priorities in the leaves of a complete binary tree whose inner nodes hold
//! the sums of their children, so proportional sampling ("the leaf where the running sum
//! passes u") and priority updates both take O(log n) — the data structure of prioritised
//! experience replay (Schaul et al. 2016).

/// Priorities of `len` leaves; all start at zero (never sampled).
#[derive(Debug, Clone)]
pub struct SumTree {
    /// Leaves live at `nodes[leaf_base + i]`; node `k`'s children are `2k` and `2k + 1`;
    /// node 1 is the root (node 0 is unused).
    nodes: Vec<f64>,
    leaf_base: usize,
    len: usize,
}

impl SumTree {
    pub fn new(len: usize) -> Self {
        let leaf_base = len.max(1).next_power_of_two();
        SumTree {
            nodes: vec![0.0; 2 * leaf_base],
            leaf_base,
            len,
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Sum of all priorities.
    pub fn total(&self) -> f64 {
        self.nodes[1]
    }

    pub fn get(&self, leaf: usize) -> f64 {
        self.nodes[self.leaf_base + leaf]
    }

    /// Sets one leaf's priority (non-negative, finite) and updates the sums above it.
    pub fn set(&mut self, leaf: usize, priority: f64) {
        debug_assert!(leaf < self.len && priority >= 0.0 && priority.is_finite());
        let mut node = self.leaf_base + leaf;
        self.nodes[node] = priority;
        while node > 1 {
            node /= 2;
            self.nodes[node] = self.nodes[2 * node] + self.nodes[2 * node + 1];
        }
    }

    /// The leaf at which the running sum of priorities (in leaf order) first exceeds
    /// `prefix`, for `prefix` in `[0, total)`. Never returns a zero-priority leaf while the
    /// total is positive (rounding at the right end falls back to the last positive leaf).
    pub fn find(&self, prefix: f64) -> usize {
        let mut node = 1;
        let mut rest = prefix.max(0.0);
        while node < self.leaf_base {
            let left = 2 * node;
            if rest < self.nodes[left] || self.nodes[left + 1] <= 0.0 {
                node = left;
            } else {
                rest -= self.nodes[left];
                node = left + 1;
            }
        }
        node - self.leaf_base
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sums_and_finds_by_hand() {
        let mut tree = SumTree::new(5);
        for (leaf, p) in [1.0, 0.0, 3.0, 2.0, 4.0].into_iter().enumerate() {
            tree.set(leaf, p);
        }
        assert_eq!(tree.total(), 10.0);
        // Running sums: [1, 1, 4, 6, 10].
        assert_eq!(tree.find(0.0), 0);
        assert_eq!(tree.find(0.99), 0);
        assert_eq!(tree.find(1.0), 2, "leaf 1 has zero priority and is skipped");
        assert_eq!(tree.find(3.99), 2);
        assert_eq!(tree.find(4.0), 3);
        assert_eq!(tree.find(6.5), 4);
        // Past the end (rounding) lands on the last positive leaf, never on padding.
        assert_eq!(tree.find(10.0), 4);
        assert_eq!(tree.find(1e9), 4);

        tree.set(2, 0.5);
        assert_eq!(tree.total(), 7.5);
        assert_eq!(tree.get(2), 0.5);
        assert_eq!(tree.find(1.2), 2);
        assert_eq!(tree.find(1.5), 3);
    }

    #[test]
    fn sampling_frequencies_follow_priorities() {
        let mut tree = SumTree::new(3);
        tree.set(0, 1.0);
        tree.set(1, 2.0);
        tree.set(2, 7.0);
        let mut counts = [0usize; 3];
        let n = 10_000;
        for k in 0..n {
            let u = (k as f64 + 0.5) / n as f64 * tree.total();
            counts[tree.find(u)] += 1;
        }
        assert_eq!(counts, [1000, 2000, 7000]);
    }

    #[test]
    fn single_leaf_and_empty() {
        let mut tree = SumTree::new(1);
        assert_eq!(tree.total(), 0.0);
        tree.set(0, 2.5);
        assert_eq!(tree.find(1.0), 0);
        assert!(SumTree::new(0).is_empty());
    }
}
