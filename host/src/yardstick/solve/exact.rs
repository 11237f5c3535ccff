//! `exact`: a minimum dominating set by integer programming with HiGHS,
//!
//! ```text
//! minimise Σ x_v   subject to   x_v + Σ_{u ∈ N(v)} x_u ≥ 1 for every v,   x binary,
//! ```
//!
//! i.e. a set cover whose rows (demands) and columns (candidates) are both the
//! closed neighbourhoods `N[v]`. Before HiGHS sees it the cover is shrunk by
//! reductions that keep the optimum value, repeated until nothing changes:
//!
//! - a row with a single column forces that column (it is in every cover);
//! - a column whose rows are a subset of another column's is dropped (swap it
//!   for the other one); of identical columns the lowest index stays;
//! - a row whose columns are a superset of another row's is dropped (covering
//!   the smaller row covers it); of identical rows the lowest index stays.
//!
//! What is left splits into connected components, solved one by one (smallest
//! first) under one shared deadline, each warm-started with its greedy cover.
//! A component whose greedy cover already meets a disjoint-rows packing lower
//! bound is solved without HiGHS. When time runs out the best cover found is
//! kept (HiGHS's incumbent or the greedy cover) together with the proven lower
//! bound (`max(packing bound, ⌈HiGHS dual bound⌉)`), and the result is only
//! called optimal when that bound meets its size.

use super::greedy::{greedy, greedy_cover, Incidence};
use super::labels::is_dominating;
use crate::yardstick::graph::OverlapGraph;
use highs::{HighsModelStatus, HighsSolutionStatus, RowProblem, Sense};
use rayon::prelude::*;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Outcome of [`exact`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExactResult {
    /// A dominating set, ascending: a minimum one when `optimal`.
    pub set: Vec<usize>,
    /// Whether `set` is proven minimum.
    pub optimal: bool,
    /// Proven lower bound on the minimum size (`== set.len()` when optimal).
    pub lower_bound: usize,
    /// Human-readable summary of how it was solved.
    pub status: String,
}

/// HiGHS runs one model at a time in this process: its task scheduler is
/// global, and concurrent runs gain nothing for these small models.
static HIGHS: Mutex<()> = Mutex::new(());

/// A minimum dominating set of `g` within `time_limit` (reductions included).
pub fn exact(g: &OverlapGraph, time_limit: Duration) -> ExactResult {
    let start = Instant::now();
    let deadline = start.checked_add(time_limit);
    let mut cover = Cover::from_graph(g);
    cover.reduce();
    let forced = cover.forced.len();
    let mut comps = cover.components();
    comps.sort_by_key(|c| (c.rows.len(), c.cols[0]));

    let mut set: Vec<usize> = cover.forced.iter().map(|&c| c as usize).collect();
    let mut lower = forced;
    let (mut by_bound, mut by_highs, mut unproven) = (0usize, 0usize, 0usize);
    for comp in &comps {
        let out = comp.solve(deadline);
        set.extend(out.chosen.iter().map(|&c| comp.cols[c] as usize));
        lower += out.lower;
        match (out.lower >= out.chosen.len(), out.used_highs) {
            (true, false) => by_bound += 1,
            (true, true) => by_highs += 1,
            (false, _) => unproven += 1,
        }
    }
    set.sort_unstable();

    let mut note = String::new();
    let fallback = greedy(g);
    if !is_dominating(g, &set) {
        // Cannot happen if the reductions are right; never return a non-cover.
        note = "; internal error: reduced solution does not dominate, greedy used".into();
        set = fallback;
        lower = 0;
    } else if set.len() > fallback.len() {
        note = "; greedy beat the best unproven solution".into();
        set = fallback;
    }
    let lower_bound = lower.min(set.len());
    let optimal = lower_bound == set.len();
    let status = format!(
        "{}: size {}, lower bound {}; {} forced, {} components ({} by bounds, {} by HiGHS, {} unproven); {:.2} s{}",
        if optimal { "optimal" } else { "time limit" },
        set.len(),
        lower_bound,
        forced,
        comps.len(),
        by_bound,
        by_highs,
        unproven,
        start.elapsed().as_secs_f64(),
        note
    );
    ExactResult {
        set,
        optimal,
        lower_bound,
        status,
    }
}

/// The set-cover form: `rows[r]` lists the alive columns covering row `r`,
/// `cols[c]` the alive rows column `c` covers (both ascending, empty when dead).
struct Cover {
    rows: Vec<Vec<u32>>,
    cols: Vec<Vec<u32>>,
    row_alive: Vec<bool>,
    col_alive: Vec<bool>,
    /// Columns in every minimum cover, removed with the rows they cover.
    forced: Vec<u32>,
}

impl Cover {
    fn from_graph(g: &OverlapGraph) -> Cover {
        let rows: Vec<Vec<u32>> = (0..g.n)
            .map(|v| {
                let mut r = g.neighbours(v).to_vec();
                let at = r.partition_point(|&u| (u as usize) < v);
                r.insert(at, v as u32);
                r
            })
            .collect();
        Cover {
            cols: rows.clone(),
            rows,
            row_alive: vec![true; g.n],
            col_alive: vec![true; g.n],
            forced: Vec::new(),
        }
    }

    /// Applies the reductions until none applies.
    fn reduce(&mut self) {
        loop {
            let mut changed = self.force();
            self.compact();
            changed |= self.drop_dominated_cols();
            self.compact();
            changed |= self.drop_dominated_rows();
            self.compact();
            if !changed {
                break;
            }
        }
    }

    /// Drops dead entries from every list.
    fn compact(&mut self) {
        let (ra, ca) = (&self.row_alive, &self.col_alive);
        self.rows.par_iter_mut().enumerate().for_each(|(r, l)| {
            if ra[r] {
                l.retain(|&c| ca[c as usize]);
            } else {
                *l = Vec::new();
            }
        });
        self.cols.par_iter_mut().enumerate().for_each(|(c, l)| {
            if ca[c] {
                l.retain(|&r| ra[r as usize]);
            } else {
                *l = Vec::new();
            }
        });
    }

    /// Forces the only column of single-column rows.
    fn force(&mut self) -> bool {
        let mut changed = false;
        for r in 0..self.rows.len() {
            if self.row_alive[r] && self.rows[r].len() == 1 {
                let c = self.rows[r][0] as usize;
                // A forced column already killed every row it covers, r included.
                debug_assert!(self.col_alive[c]);
                self.col_alive[c] = false;
                self.forced.push(c as u32);
                for &r2 in &self.cols[c] {
                    self.row_alive[r2 as usize] = false;
                }
                changed = true;
            }
        }
        changed
    }

    /// Drops columns covering nothing, and columns whose rows are a subset of
    /// another column's (strictly, or equal with a lower index).
    fn drop_dominated_cols(&mut self) -> bool {
        let (cols, rows) = (&self.cols, &self.rows);
        let dead: Vec<usize> = (0..cols.len())
            .into_par_iter()
            .filter(|&v| {
                self.col_alive[v]
                    && (cols[v].is_empty()
                        || supersets(cols, rows, v).any(|w| cols[w].len() > cols[v].len() || w < v))
            })
            .collect();
        for &v in &dead {
            self.col_alive[v] = false;
        }
        !dead.is_empty()
    }

    /// Drops rows whose columns are a superset of another row's (strictly,
    /// or equal with a higher index).
    fn drop_dominated_rows(&mut self) -> bool {
        let (cols, rows) = (&self.cols, &self.rows);
        let dead: Vec<usize> = (0..rows.len())
            .into_par_iter()
            .filter(|&b| self.row_alive[b])
            .flat_map_iter(|b| {
                supersets(rows, cols, b).filter(move |&a| rows[a].len() > rows[b].len() || b < a)
            })
            .collect();
        let mut changed = false;
        for a in dead {
            changed |= std::mem::replace(&mut self.row_alive[a], false);
        }
        changed
    }

    /// Connected components of the alive rows and columns.
    fn components(&self) -> Vec<Component> {
        let nc = self.cols.len();
        let mut parent: Vec<u32> = (0..nc as u32).collect();
        fn find(p: &mut [u32], mut x: u32) -> u32 {
            while p[x as usize] != x {
                p[x as usize] = p[p[x as usize] as usize];
                x = p[x as usize];
            }
            x
        }
        for (r, l) in self.rows.iter().enumerate() {
            if self.row_alive[r] {
                let a = find(&mut parent, l[0]);
                for &c in &l[1..] {
                    let b = find(&mut parent, c);
                    parent[b as usize] = a;
                }
            }
        }
        // Component ids in order of their lowest column; local column ids ascending.
        let mut comp_of = vec![u32::MAX; nc];
        let mut local = vec![0u32; nc];
        let mut comps: Vec<Component> = Vec::new();
        for c in 0..nc {
            if !self.col_alive[c] {
                continue;
            }
            let root = find(&mut parent, c as u32) as usize;
            if comp_of[root] == u32::MAX {
                comp_of[root] = comps.len() as u32;
                comps.push(Component::default());
            }
            let k = comp_of[root] as usize;
            comp_of[c] = k as u32;
            local[c] = comps[k].cols.len() as u32;
            comps[k].cols.push(c as u32);
            comps[k].col_rows.push(Vec::new());
        }
        for (r, l) in self.rows.iter().enumerate() {
            if self.row_alive[r] {
                let comp = &mut comps[comp_of[l[0] as usize] as usize];
                let lr = comp.rows.len() as u32;
                let row: Vec<u32> = l.iter().map(|&c| local[c as usize]).collect();
                for &c in &row {
                    comp.col_rows[c as usize].push(lr);
                }
                comp.rows.push(row);
            }
        }
        comps
    }
}

/// Elements `x != y` of `sets` whose set contains `sets[y]` (non-empty),
/// found among the holders of `sets[y]`'s rarest element; `trans` is the
/// transpose of `sets`.
fn supersets<'a>(
    sets: &'a [Vec<u32>],
    trans: &'a [Vec<u32>],
    y: usize,
) -> impl Iterator<Item = usize> + 'a {
    let sy = &sets[y];
    let rare = sy.iter().min_by_key(|&&e| trans[e as usize].len());
    let candidates = rare.map_or(&[][..], |&e| &trans[e as usize][..]);
    candidates
        .iter()
        .map(|&x| x as usize)
        .filter(move |&x| x != y && sets[x].len() >= sy.len() && is_subset(sy, &sets[x]))
}

/// Whether ascending `a` is a subset of ascending `b`.
fn is_subset(a: &[u32], b: &[u32]) -> bool {
    let mut j = 0;
    for &x in a {
        while j < b.len() && b[j] < x {
            j += 1;
        }
        if j == b.len() || b[j] != x {
            return false;
        }
        j += 1;
    }
    true
}

/// One connected component of the reduced cover, in local ids.
#[derive(Default)]
struct Component {
    /// Original vertex of each local column, ascending.
    cols: Vec<u32>,
    /// Local columns of each row.
    rows: Vec<Vec<u32>>,
    /// Local rows of each column.
    col_rows: Vec<Vec<u32>>,
}

impl Incidence for Component {
    fn n_cols(&self) -> usize {
        self.cols.len()
    }

    fn n_rows(&self) -> usize {
        self.rows.len()
    }

    fn rows_of(&self, c: usize) -> impl Iterator<Item = usize> + '_ {
        self.col_rows[c].iter().map(|&r| r as usize)
    }

    fn cols_of(&self, r: usize) -> impl Iterator<Item = usize> + '_ {
        self.rows[r].iter().map(|&c| c as usize)
    }
}

/// A component's cover and what is proven about it.
struct Solved {
    /// Local columns.
    chosen: Vec<usize>,
    /// Proven lower bound on the component's minimum.
    lower: usize,
    used_highs: bool,
}

impl Component {
    fn solve(&self, deadline: Option<Instant>) -> Solved {
        let greedy = greedy_cover(self);
        let pack = self.packing_bound();
        let done = |chosen: Vec<usize>, lower: usize, used_highs| Solved {
            lower: lower.min(chosen.len()),
            chosen,
            used_highs,
        };
        if pack >= greedy.len() {
            return done(greedy, pack, false);
        }
        let left = deadline.map_or(Duration::MAX, |d| {
            d.saturating_duration_since(Instant::now())
        });
        if left.is_zero() {
            return done(greedy, pack, false);
        }
        match self.highs(&greedy, left) {
            Some((chosen, lower)) if chosen.len() < greedy.len() => {
                done(chosen, lower.max(pack), true)
            }
            Some((_, lower)) => done(greedy, lower.max(pack), true),
            None => done(greedy, pack, true),
        }
    }

    /// Size of a set of rows no two of which share a column: every cover
    /// needs a distinct column for each.
    fn packing_bound(&self) -> usize {
        let mut order: Vec<usize> = (0..self.rows.len()).collect();
        order.sort_by_key(|&r| (self.rows[r].len(), r));
        let mut used = vec![false; self.cols.len()];
        let mut count = 0;
        for r in order {
            let row = &self.rows[r];
            if row.iter().all(|&c| !used[c as usize]) {
                count += 1;
                for &c in row {
                    used[c as usize] = true;
                }
            }
        }
        count
    }

    /// Whether local columns `chosen` cover every row.
    fn covers(&self, chosen: &[usize]) -> bool {
        let mut taken = vec![false; self.cols.len()];
        for &c in chosen {
            taken[c] = true;
        }
        self.rows
            .iter()
            .all(|row| row.iter().any(|&c| taken[c as usize]))
    }

    /// HiGHS's best cover (if it found one that covers) and its proven lower
    /// bound, within `time`; `None` when HiGHS fails outright.
    fn highs(&self, start: &[usize], time: Duration) -> Option<(Vec<usize>, usize)> {
        let _lock = HIGHS.lock().unwrap_or_else(|e| e.into_inner());
        let mut pb = RowProblem::new();
        let x: Vec<_> = (0..self.cols.len())
            .map(|_| pb.add_integer_column(1.0, 0.0..=1.0))
            .collect();
        for row in &self.rows {
            pb.add_row(1.0.., row.iter().map(|&c| (x[c as usize], 1.0)));
        }
        let mut model = pb.try_optimise(Sense::Minimise).ok()?;
        model.make_quiet();
        // Options a HiGHS build may lack are simply left at their defaults.
        let _ = model.try_set_option("time_limit", time.as_secs_f64().min(1e9));
        // The objective is an integer: a gap below 1 proves optimality, and
        // the relative gap (default 1e-4) must not cut the search short.
        let _ = model.try_set_option("mip_rel_gap", 0.0);
        let _ = model.try_set_option("mip_abs_gap", 0.5);
        let mut warm = vec![0.0; self.cols.len()];
        for &c in start {
            warm[c] = 1.0;
        }
        let _ = model.try_set_solution(Some(&warm), None, None, None);
        let solved = model.try_solve().ok()?;
        let status = solved.status();
        let mut chosen = Vec::new();
        if solved.primal_solution_status() == HighsSolutionStatus::Feasible {
            let sol = solved.get_solution();
            chosen = (0..self.cols.len())
                .filter(|&c| sol.columns()[c] > 0.5)
                .collect();
        }
        if chosen.is_empty() || !self.covers(&chosen) {
            chosen = start.to_vec();
        }
        let mut lower = solved
            .double_info_value(c"mip_dual_bound")
            .ok()
            .filter(|d| d.is_finite() && *d > 0.0)
            .map_or(0, |d| (d - 1e-6).ceil() as usize);
        if status == HighsModelStatus::Optimal
            && solved.primal_solution_status() == HighsSolutionStatus::Feasible
        {
            let value = solved.objective_value().round() as usize;
            if value == chosen.len() {
                lower = lower.max(value);
            }
        }
        Some((chosen, lower))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reductions_solve_a_path_without_highs() {
        let g = OverlapGraph::from_edges(7, &[(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6)]);
        let r = exact(&g, Duration::from_secs(10));
        assert_eq!(r.set.len(), 3);
        assert!(r.optimal && r.lower_bound == 3, "{r:?}");
    }

    #[test]
    fn subset_test() {
        assert!(is_subset(&[], &[1]));
        assert!(is_subset(&[1, 3], &[0, 1, 2, 3]));
        assert!(!is_subset(&[1, 4], &[0, 1, 2, 3]));
        assert!(!is_subset(&[1], &[]));
    }

    #[test]
    fn twins_keep_one_column() {
        // Complete graph: all columns identical, one stays and is forced.
        let edges: Vec<_> = (0..5)
            .flat_map(|a| (a + 1..5).map(move |b| (a, b)))
            .collect();
        let g = OverlapGraph::from_edges(5, &edges);
        let mut c = Cover::from_graph(&g);
        c.reduce();
        assert_eq!(c.forced, vec![0]);
        assert!(c.row_alive.iter().all(|&a| !a));
    }
}
