//! A bounding-volume hierarchy over the bounded primitives of a scene.
//!
//! Built once per cast (a few hundred primitives take microseconds): primitives sorted along
//! the longest axis of their centroid bounds and split by the surface-area heuristic, up to
//! `LEAF_SIZE` per leaf. Traversal
//! visits the nearer child first and prunes boxes beyond the closest hit so far.

/// Axis-aligned box.
#[derive(Debug, Clone, Copy)]
pub struct Aabb {
    pub lo: [f64; 3],
    pub hi: [f64; 3],
}

impl Aabb {
    fn empty() -> Self {
        Aabb {
            lo: [f64::INFINITY; 3],
            hi: [f64::NEG_INFINITY; 3],
        }
    }

    fn grow(&mut self, other: &Aabb) {
        for k in 0..3 {
            self.lo[k] = self.lo[k].min(other.lo[k]);
            self.hi[k] = self.hi[k].max(other.hi[k]);
        }
    }

    fn area(&self) -> f64 {
        let e = [
            self.hi[0] - self.lo[0],
            self.hi[1] - self.lo[1],
            self.hi[2] - self.lo[2],
        ];
        e[0] * e[1] + e[1] * e[2] + e[2] * e[0]
    }

    fn centre(&self, k: usize) -> f64 {
        0.5 * (self.lo[k] + self.hi[k])
    }

    /// Entry distance of the ray (slab test) if it meets the box within `[0, t_max]`.
    #[inline]
    pub fn entry(&self, o: [f64; 3], inv_d: [f64; 3], t_max: f64) -> Option<f64> {
        let mut t0 = 0.0f64;
        let mut t1 = t_max;
        for k in 0..3 {
            let a = (self.lo[k] - o[k]) * inv_d[k];
            let b = (self.hi[k] - o[k]) * inv_d[k];
            // `min`/`max` drop the NaN of 0 * inf (ray in the slab plane), which keeps the
            // test conservative.
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        (t0 <= t1).then_some(t0)
    }
}

const LEAF_SIZE: usize = 4;
const MAX_SAH_DEPTH: usize = 24;

enum Node {
    Leaf {
        bounds: Aabb,
        start: usize,
        end: usize,
    },
    Inner {
        bounds: Aabb,
        left: usize,
        right: usize,
    },
}

impl Node {
    fn bounds(&self) -> &Aabb {
        match self {
            Node::Leaf { bounds, .. } | Node::Inner { bounds, .. } => bounds,
        }
    }
}

pub struct Bvh {
    nodes: Vec<Node>,
    /// Primitive ids in leaf order.
    order: Vec<usize>,
}

impl Bvh {
    /// Build over `(id, bounds)` items.
    pub fn build(items: &[(usize, Aabb)]) -> Self {
        let mut bvh = Bvh {
            nodes: Vec::with_capacity(2 * items.len().max(1)),
            order: Vec::with_capacity(items.len()),
        };
        if !items.is_empty() {
            let mut work = items.to_vec();
            bvh.build_node(&mut work, 0);
        }
        bvh
    }

    fn build_node(&mut self, items: &mut [(usize, Aabb)], depth: usize) -> usize {
        let mut bounds = Aabb::empty();
        let mut cb = Aabb::empty();
        for (_, b) in items.iter() {
            bounds.grow(b);
            let c = [b.centre(0), b.centre(1), b.centre(2)];
            cb.grow(&Aabb { lo: c, hi: c });
        }
        let index = self.nodes.len();
        if items.len() <= LEAF_SIZE {
            let start = self.order.len();
            self.order.extend(items.iter().map(|(id, _)| *id));
            self.nodes.push(Node::Leaf {
                bounds,
                start,
                end: self.order.len(),
            });
            return index;
        }
        let axis = (0..3)
            .max_by(|&a, &b| (cb.hi[a] - cb.lo[a]).total_cmp(&(cb.hi[b] - cb.lo[b])))
            .unwrap_or(0);
        // Sort along the axis (ties by id: the tree does not depend on input order), then
        // split where the surface-area heuristic is cheapest: scenes mix 20 m façades with
        // 0.3 m spheres, where a median split makes loose, overlapping boxes.
        items.sort_unstable_by(|x, y| {
            x.1.centre(axis)
                .total_cmp(&y.1.centre(axis))
                .then(x.0.cmp(&y.0))
        });
        let n = items.len();
        let mut right_area = vec![0.0; n];
        let mut acc = Aabb::empty();
        for i in (1..n).rev() {
            acc.grow(&items[i].1);
            right_area[i] = acc.area();
        }
        let mut acc = Aabb::empty();
        let mut mid = n / 2;
        // Deep in the tree fall back to the median, which bounds the depth (and so the
        // traversal stack) at MAX_SAH_DEPTH + log2(n).
        let mut best_cost = if depth < MAX_SAH_DEPTH {
            f64::INFINITY
        } else {
            f64::NEG_INFINITY
        };
        for i in 1..n {
            acc.grow(&items[i - 1].1);
            let cost = acc.area() * i as f64 + right_area[i] * (n - i) as f64;
            if cost < best_cost {
                best_cost = cost;
                mid = i;
            }
        }
        // Placeholder, patched once the children exist.
        self.nodes.push(Node::Leaf {
            bounds,
            start: 0,
            end: 0,
        });
        let (lo, hi) = items.split_at_mut(mid);
        let left = self.build_node(lo, depth + 1);
        let right = self.build_node(hi, depth + 1);
        self.nodes[index] = Node::Inner {
            bounds,
            left,
            right,
        };
        index
    }

    /// Closest hit `(t, id)` with `t < t_max`; `hit(id)` returns the primitive's distance.
    #[inline]
    pub fn closest(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        mut t_max: f64,
        hit: impl Fn(usize) -> Option<f64>,
    ) -> Option<(f64, usize)> {
        if self.nodes.is_empty() {
            return None;
        }
        let inv_d = [1.0 / d[0], 1.0 / d[1], 1.0 / d[2]];
        let mut best: Option<(f64, usize)> = None;
        // (node, entry distance): a node is skipped on pop if a hit closer than its entry
        // has been found since it was pushed.
        let mut stack: [(usize, f64); 64] = [(0, 0.0); 64];
        let mut top = 0usize;
        let t_root = self.nodes[0].bounds().entry(o, inv_d, t_max)?;
        stack[top] = (0, t_root);
        top += 1;
        while top > 0 {
            top -= 1;
            let (node, t_entry) = stack[top];
            if t_entry > t_max {
                continue;
            }
            match &self.nodes[node] {
                Node::Leaf { start, end, .. } => {
                    for &id in &self.order[*start..*end] {
                        if let Some(t) = hit(id) {
                            // Equal distances: the lower id wins, independent of traversal.
                            let better = match best {
                                None => t < t_max,
                                Some((bt, bid)) => t < bt || (t == bt && id < bid),
                            };
                            if better {
                                best = Some((t, id));
                                t_max = t;
                            }
                        }
                    }
                }
                Node::Inner { left, right, .. } => {
                    let tl = self.nodes[*left].bounds().entry(o, inv_d, t_max);
                    let tr = self.nodes[*right].bounds().entry(o, inv_d, t_max);
                    // Push the farther child first so the nearer one is popped next.
                    let mut push = |n: usize, t: f64| {
                        if top < stack.len() {
                            stack[top] = (n, t);
                            top += 1;
                        }
                    };
                    match (tl, tr) {
                        (Some(a), Some(b)) if a <= b => {
                            push(*right, b);
                            push(*left, a);
                        }
                        (Some(a), Some(b)) => {
                            push(*left, a);
                            push(*right, b);
                        }
                        (Some(a), None) => push(*left, a),
                        (None, Some(b)) => push(*right, b),
                        (None, None) => {}
                    }
                }
            }
        }
        best
    }
}
