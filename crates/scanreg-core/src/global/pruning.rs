//! Outlier pruning by pairwise length consistency (TEASER++, Yang, Shi & Carlone 2020, §V;
//! KISS-Matcher, Lim et al. 2025).
//!
//! A rigid transform preserves distances, so two correct correspondences `(s_i, t_i)`,
//! `(s_j, t_j)` satisfy `| |s_i − s_j| − |t_i − t_j| | <= 2β` with `β` the noise bound of one
//! point. Correspondences are the vertices of a graph with an edge wherever that holds; the
//! inliers form a clique, so the largest clique is the candidate inlier set.
//!
//! The maximum clique is found by branch and bound (Tomita & Seki's MCQ: candidates coloured
//! greedily, a clique grown from them can gain at most one vertex per colour) over bitset
//! adjacency, seeded by a greedy clique and restricted by k-core numbers: a clique of size
//! `s + 1` lies inside the `s`-core, so once a clique of size `s` is known every vertex of core
//! number below `s` is dropped (the pruning of Rossi et al.'s PMC, which TEASER++ uses). The
//! search is sequential and visits vertices in a fixed order, so it is deterministic; a budget
//! of work (bitset words visited by the colourings: the cost of a node grows with its candidate
//! set, so counting nodes alone let a dense graph of 3000 correspondences run for a minute)
//! bounds pathological graphs (then the best clique found so far is returned and `exact` is
//! false).

use rayon::prelude::*;

/// An undirected graph as rows of bits.
pub struct Graph {
    n: usize,
    words: usize,
    bits: Vec<u64>,
}

impl Graph {
    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    fn row(&self, i: usize) -> &[u64] {
        &self.bits[i * self.words..(i + 1) * self.words]
    }

    pub fn has_edge(&self, i: usize, j: usize) -> bool {
        self.row(i)[j / 64] >> (j % 64) & 1 == 1
    }

    pub fn degree(&self, i: usize) -> usize {
        self.row(i).iter().map(|w| w.count_ones() as usize).sum()
    }
}

/// The length-consistency graph of `n` correspondences (`source`, `target`: `n * 3` each):
/// an edge where the two lengths differ by at most `tolerance`.
pub fn consistency_graph(source: &[f64], target: &[f64], tolerance: f64) -> Graph {
    let n = source.len() / 3;
    let words = n.div_ceil(64).max(1);
    let dist = |p: &[f64], i: usize, j: usize| {
        let (a, b) = (&p[3 * i..3 * i + 3], &p[3 * j..3 * j + 3]);
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    };
    let mut bits = vec![0u64; n * words];
    bits.par_chunks_mut(words).enumerate().for_each(|(i, row)| {
        for j in 0..n {
            if j != i && (dist(source, i, j) - dist(target, i, j)).abs() <= tolerance {
                row[j / 64] |= 1 << (j % 64);
            }
        }
    });
    Graph { n, words, bits }
}

/// Core number of every vertex (Batagelj & Zaversnik 2003), for vertices with `active` set;
/// inactive vertices are removed from the graph first (core number 0).
pub fn core_numbers(g: &Graph, active: &[bool]) -> Vec<usize> {
    let n = g.n;
    let mut deg: Vec<usize> = (0..n)
        .map(|i| {
            if !active[i] {
                return 0;
            }
            ones(g.row(i)).filter(|&j| active[j]).count()
        })
        .collect();
    let maxd = deg.iter().copied().max().unwrap_or(0);
    let mut buckets: Vec<Vec<usize>> = vec![Vec::new(); maxd + 1];
    for i in (0..n).filter(|&i| active[i]) {
        buckets[deg[i]].push(i);
    }
    let mut core = vec![0; n];
    let mut done = vec![false; n];
    let mut d = 0;
    let mut level = 0;
    let mut remaining = active.iter().filter(|&&a| a).count();
    while remaining > 0 {
        // The vertex of lowest current degree (bucket entries can be stale: a vertex is
        // pushed again whenever its degree drops, so skip those that moved).
        let mut pick = None;
        while pick.is_none() && d <= maxd {
            match buckets[d].pop() {
                Some(v) if !done[v] && deg[v] == d => pick = Some(v),
                Some(_) => {}
                None => d += 1,
            }
        }
        let Some(v) = pick else { break };
        done[v] = true;
        remaining -= 1;
        level = level.max(d);
        core[v] = level;
        for u in ones(g.row(v)) {
            if active[u] && !done[u] && deg[u] > 0 {
                deg[u] -= 1;
                buckets[deg[u]].push(u);
                d = d.min(deg[u]);
            }
        }
    }
    core
}

/// A maximum clique (vertex indices, ascending) among the vertices with `active` set, and
/// whether the search finished within `budget` bitset-word operations (exact) or was cut
/// short.
pub fn max_clique(g: &Graph, active: &[bool], budget: usize) -> (Vec<usize>, bool) {
    let n = g.n;
    let core = core_numbers(g, active);
    // Greedy seed: from each of the first vertices in decreasing core order, add the next
    // vertex (in that order) adjacent to all chosen so far, tracking the common neighbours
    // as a bitset.
    let mut order: Vec<usize> = (0..n).filter(|&i| active[i]).collect();
    order.sort_by(|&a, &b| core[b].cmp(&core[a]).then(a.cmp(&b)));
    let mut best: Vec<usize> = Vec::new();
    for &v in order.iter().take(16) {
        if core[v] < best.len() {
            break;
        }
        let mut clique = vec![v];
        let mut common = g.row(v).to_vec();
        for &u in &order {
            if core[u] < best.len() {
                break;
            }
            if common[u / 64] >> (u % 64) & 1 == 1 {
                clique.push(u);
                for (a, b) in common.iter_mut().zip(g.row(u)) {
                    *a &= b;
                }
            }
        }
        if clique.len() > best.len() {
            best = clique;
        }
    }
    // No clique is larger than the largest core number + 1: a seed of that size is maximum
    // (the usual case for a clean inlier set, where the search below would only confirm it).
    let max_core = order.first().map_or(0, |&v| core[v]);
    if best.len() > max_core {
        best.sort_unstable();
        return (best, true);
    }
    let mut search = Search {
        g,
        best,
        budget,
        expansions: 0,
    };
    // Candidates that can still beat the seed: core number >= its size.
    let mut cand = vec![0u64; g.words];
    for &v in &order {
        if core[v] >= search.best.len() {
            cand[v / 64] |= 1 << (v % 64);
        }
    }
    let mut clique = Vec::new();
    search.expand(&mut clique, cand);
    let exact = search.expansions <= search.budget;
    let mut best = search.best;
    best.sort_unstable();
    (best, exact)
}

struct Search<'a> {
    g: &'a Graph,
    best: Vec<usize>,
    budget: usize,
    expansions: usize,
}

fn ones(bits: &[u64]) -> impl Iterator<Item = usize> + '_ {
    bits.iter().enumerate().flat_map(|(w, &word)| {
        let mut x = word;
        std::iter::from_fn(move || {
            if x == 0 {
                return None;
            }
            let b = x.trailing_zeros() as usize;
            x &= x - 1;
            Some(w * 64 + b)
        })
    })
}

fn first_one(bits: &[u64]) -> Option<usize> {
    bits.iter()
        .position(|&w| w != 0)
        .map(|w| w * 64 + bits[w].trailing_zeros() as usize)
}

impl Search<'_> {
    /// Greedy colouring of `cand`: vertices in colour order and each one's colour (1-based).
    fn colour(&mut self, cand: &[u64]) -> (Vec<usize>, Vec<usize>) {
        let mut uncoloured = cand.to_vec();
        let mut order = Vec::new();
        let mut colours = Vec::new();
        let mut k = 0;
        let words = self.g.words;
        while uncoloured.iter().any(|&w| w != 0) {
            k += 1;
            let mut q = uncoloured.clone();
            self.expansions += words;
            while let Some(v) = first_one(&q) {
                self.expansions += words;
                order.push(v);
                colours.push(k);
                uncoloured[v / 64] &= !(1 << (v % 64));
                q[v / 64] &= !(1 << (v % 64));
                for (a, b) in q.iter_mut().zip(self.g.row(v)) {
                    *a &= !b;
                }
            }
        }
        (order, colours)
    }

    fn expand(&mut self, clique: &mut Vec<usize>, mut cand: Vec<u64>) {
        if self.expansions > self.budget {
            return;
        }
        let (order, colours) = self.colour(&cand);
        for idx in (0..order.len()).rev() {
            if clique.len() + colours[idx] <= self.best.len() || self.expansions > self.budget {
                return;
            }
            let v = order[idx];
            clique.push(v);
            let next: Vec<u64> = cand.iter().zip(self.g.row(v)).map(|(a, b)| a & b).collect();
            if next.iter().all(|&w| w == 0) {
                if clique.len() > self.best.len() {
                    self.best = clique.clone();
                }
            } else {
                self.expand(clique, next);
            }
            clique.pop();
            cand[v / 64] &= !(1 << (v % 64));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn graph(n: usize, edges: &[(usize, usize)]) -> Graph {
        let words = n.div_ceil(64).max(1);
        let mut bits = vec![0u64; n * words];
        for &(a, b) in edges {
            bits[a * words + b / 64] |= 1 << (b % 64);
            bits[b * words + a / 64] |= 1 << (a % 64);
        }
        Graph { n, words, bits }
    }

    #[test]
    fn finds_the_maximum_clique_not_the_greedy_one() {
        // A 4-clique {3,4,5,6}; vertex 0 has the highest degree but lies in triangles only.
        let mut e = vec![(0, 1), (0, 2), (1, 2), (0, 7), (0, 8), (7, 8), (0, 3)];
        for a in 3..7 {
            for b in a + 1..7 {
                e.push((a, b));
            }
        }
        let g = graph(9, &e);
        let (c, exact) = max_clique(&g, &[true; 9], 10_000);
        assert!(exact);
        assert_eq!(c, vec![3, 4, 5, 6]);
        let mut active = [true; 9];
        active[4] = false;
        let (c, _) = max_clique(&g, &active, 10_000);
        assert_eq!(c.len(), 3);
    }

    #[test]
    fn core_numbers_of_a_clique_with_a_tail() {
        let g = graph(5, &[(0, 1), (0, 2), (1, 2), (2, 3), (3, 4)]);
        assert_eq!(core_numbers(&g, &[true; 5]), vec![2, 2, 2, 1, 1]);
    }

    #[test]
    fn consistent_lengths_make_edges() {
        let s = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 5.0, 0.0, 0.0];
        let t = [1.0, 1.0, 1.0, 1.0, 2.0, 1.0, 1.0, 1.0, 1.0];
        let g = consistency_graph(&s, &t, 0.1);
        assert!(g.has_edge(0, 1) && g.has_edge(1, 0));
        assert!(!g.has_edge(0, 2) && !g.has_edge(1, 2));
    }
}
