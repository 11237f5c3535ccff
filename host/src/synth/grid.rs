//! Ray casting against the scene's boxes through a uniform 2D grid over the
//! floor plan: a ray walks the cells it crosses (Amanatides–Woo) and slab-tests
//! only the boxes registered in them, stopping as soon as the nearest hit lies
//! before the current cell's exit. Boxes that cover most of the plan (floor,
//! ceiling) are tested once per ray instead of being registered everywhere.
//!
//! For bundles of neighbouring rays [`Gatherer`] collects the few boxes that
//! can meet a given convex region, so that each ray of the bundle is tested
//! against that short list only (see `render`).

use super::scene_box::SceneBox;

/// Stand-in for a zero direction component: keeps every slab product finite
/// or infinite, never `0 * inf = NaN`.
const TINY: f64 = 1e-300;

/// A box as the caster stores it, with its index in the scene.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Slab {
    min: [f64; 3],
    max: [f64; 3],
    id: u32,
}

/// Nearest hit of a ray: parameter `t` along the direction as given, and the
/// index of the box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Hit {
    pub t: f64,
    pub id: u32,
}

/// Boxes bucketed by the floor-plan cells their footprint touches.
#[derive(Debug, Clone)]
pub(crate) struct Grid {
    lo: [f64; 2],
    hi: [f64; 2],
    cell: f64,
    inv_cell: f64,
    nx: usize,
    ny: usize,
    /// Cell `c`'s boxes are `items[start[c]..start[c + 1]]`.
    start: Vec<u32>,
    items: Vec<Slab>,
    /// Boxes tested for every ray.
    global: Vec<Slab>,
    /// Every box, by index.
    all: Vec<Slab>,
}

/// The face of a box a ray enters through: box index, axis, and whether the
/// ray runs towards +axis (so enters through the box's minimum side).
pub(crate) type Face = (u32, usize, bool);

impl Grid {
    /// Indexes `boxes` in cells of `cell` metres.
    pub(crate) fn build(boxes: &[SceneBox], cell: f64) -> Grid {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for b in boxes {
            for a in 0..2 {
                lo[a] = lo[a].min(b.min[a]);
                hi[a] = hi[a].max(b.max[a]);
            }
        }
        if boxes.is_empty() {
            (lo, hi) = ([0.0; 2], [cell; 2]);
        }
        let nx = (((hi[0] - lo[0]) / cell).ceil() as usize).max(1);
        let ny = (((hi[1] - lo[1]) / cell).ceil() as usize).max(1);
        let plan_area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
        let mut global = Vec::new();
        let mut buckets: Vec<Vec<Slab>> = vec![Vec::new(); nx * ny];
        let all: Vec<Slab> = boxes
            .iter()
            .enumerate()
            .map(|(id, b)| Slab {
                min: b.min,
                max: b.max,
                id: id as u32,
            })
            .collect();
        for (b, &slab) in boxes.iter().zip(&all) {
            let area = (b.max[0] - b.min[0]) * (b.max[1] - b.min[1]);
            if area > 0.25 * plan_area {
                global.push(slab);
                continue;
            }
            // Closed footprint, widened a little: a box touching a cell border
            // is in both cells, so no ray can slip past it.
            let eps = 1e-9;
            let cells = |a: usize, n: usize| {
                let c0 = ((b.min[a] - eps - lo[a]) / cell).floor().max(0.0) as usize;
                let c1 = ((b.max[a] + eps - lo[a]) / cell).floor().max(0.0) as usize;
                c0.min(n - 1)..=c1.min(n - 1)
            };
            for iy in cells(1, ny) {
                for ix in cells(0, nx) {
                    buckets[iy * nx + ix].push(slab);
                }
            }
        }
        let mut start = Vec::with_capacity(nx * ny + 1);
        let mut items = Vec::new();
        start.push(0);
        for bucket in buckets {
            items.extend(bucket);
            start.push(items.len() as u32);
        }
        Grid {
            lo,
            hi,
            cell,
            inv_cell: 1.0 / cell,
            nx,
            ny,
            start,
            items,
            global,
            all,
        }
    }

    /// The face through which `origin + t dir` enters the box it hits first
    /// (`hit`, from [`Grid::cast`] with the same ray); `None` when the ray
    /// starts inside that box or enters within a nanometre of the face's edges.
    pub(crate) fn entry_face(&self, o: [f64; 3], d: [f64; 3], hit: Hit) -> Option<Face> {
        const MARGIN: f64 = 1e-9;
        let s = &self.all[hit.id as usize];
        let d = d.map(|c| if c == 0.0 { TINY } else { c });
        let mut near = [0.0; 3];
        for a in 0..3 {
            let ta = (s.min[a] - o[a]) / d[a];
            let tb = (s.max[a] - o[a]) / d[a];
            near[a] = min(ta, tb);
        }
        let axis = (0..3).fold(0, |m, a| if near[a] > near[m] { a } else { m });
        let inside = (0..3).filter(|&b| b != axis).all(|b| {
            let p = o[b] + d[b] * hit.t;
            p > s.min[b] + MARGIN && p < s.max[b] - MARGIN
        });
        (near[axis] >= 0.0 && inside).then_some((hit.id, axis, d[axis] > 0.0))
    }

    /// Nearest hit along `origin + t dir` with `0 <= t <= t_max` (`dir` need
    /// not be unit: `t` is in its units).
    #[inline]
    pub(crate) fn cast(&self, o: [f64; 3], d: [f64; 3], t_max: f64) -> Option<Hit> {
        let d = d.map(|c| if c == 0.0 { TINY } else { c });
        let inv = [1.0 / d[0], 1.0 / d[1], 1.0 / d[2]];
        let mut best = Hit {
            t: t_max,
            id: u32::MAX,
        };
        for s in &self.global {
            slab_test(s, o, inv, &mut best);
        }
        // The part of the ray over the plan.
        let (mut t0, mut t1) = (0.0f64, best.t);
        for a in 0..2 {
            let ta = (self.lo[a] - o[a]) * inv[a];
            let tb = (self.hi[a] - o[a]) * inv[a];
            t0 = max(t0, min(ta, tb));
            t1 = min(t1, max(ta, tb));
        }
        if t0 <= t1 {
            self.walk(o, d, inv, t0, t1, &mut best);
        }
        (best.id != u32::MAX).then_some(best)
    }

    /// Visits the cells the ray crosses between `t0` and `t1`, nearest first.
    #[inline]
    fn walk(&self, o: [f64; 3], d: [f64; 3], inv: [f64; 3], t0: f64, t1: f64, best: &mut Hit) {
        let cell_of = |a: usize, n: usize| {
            // Truncation is floor for the non-negative values kept.
            let c = ((o[a] + d[a] * t0 - self.lo[a]) * self.inv_cell).max(0.0);
            (c as usize).min(n - 1) as isize
        };
        let (mut ix, mut iy) = (cell_of(0, self.nx), cell_of(1, self.ny));
        let setup = |a: usize, i: isize| -> (isize, f64, f64) {
            if d[a] > 0.0 {
                let edge = self.lo[a] + (i + 1) as f64 * self.cell;
                (1, (edge - o[a]) * inv[a], self.cell * inv[a])
            } else {
                let edge = self.lo[a] + i as f64 * self.cell;
                (-1, (edge - o[a]) * inv[a], -self.cell * inv[a])
            }
        };
        let (sx, mut tx, dtx) = setup(0, ix);
        let (sy, mut ty, dty) = setup(1, iy);
        let (nx, ny) = (self.nx as isize, self.ny as isize);
        loop {
            let c = iy as usize * self.nx + ix as usize;
            let (a, b) = (self.start[c] as usize, self.start[c + 1] as usize);
            for s in &self.items[a..b] {
                slab_test(s, o, inv, best);
            }
            let exit = min(tx, ty);
            if best.t <= exit || exit >= t1 {
                return;
            }
            if tx < ty {
                ix += sx;
                if ix < 0 || ix >= nx {
                    return;
                }
                tx += dtx;
            } else {
                iy += sy;
                if iy < 0 || iy >= ny {
                    return;
                }
                ty += dty;
            }
        }
    }
}

/// Collects the boxes that meet an axis-aligned region, each once, for rays
/// from one origin.
pub(crate) struct Gatherer {
    /// Per box: the tag of the last gathering that took it.
    marks: Vec<u32>,
    tag: u32,
    /// The boxes of the last gathering, relative to the rays' origin (the
    /// very differences `box - origin` the slab test would compute).
    list: Vec<Slab>,
}

impl Gatherer {
    /// A gatherer for `grid`'s boxes.
    pub(crate) fn new(grid: &Grid) -> Gatherer {
        Gatherer {
            marks: vec![0; grid.all.len()],
            tag: 0,
            list: Vec::new(),
        }
    }

    /// Gathers the boxes meeting `lo..=hi` for rays from `origin`; `false`
    /// (and the list incomplete) when there are more than `limit`.
    pub(crate) fn gather(
        &mut self,
        grid: &Grid,
        origin: [f64; 3],
        lo: [f64; 3],
        hi: [f64; 3],
        limit: usize,
    ) -> bool {
        self.list.clear();
        self.tag = self.tag.wrapping_add(1);
        if self.tag == 0 {
            self.marks.fill(0);
            self.tag = 1;
        }
        let meets = |s: &Slab| (0..3).all(|a| s.min[a] <= hi[a] && s.max[a] >= lo[a]);
        let relative = |s: &Slab| Slab {
            min: [0, 1, 2].map(|a| s.min[a] - origin[a]),
            max: [0, 1, 2].map(|a| s.max[a] - origin[a]),
            id: s.id,
        };
        for s in &grid.global {
            if meets(s) {
                self.list.push(relative(s));
            }
        }
        let range = |a: usize, n: usize| {
            let c0 = ((lo[a] - grid.lo[a]) * grid.inv_cell).floor().max(0.0) as usize;
            let c1 = ((hi[a] - grid.lo[a]) * grid.inv_cell).floor().max(0.0) as usize;
            c0.min(n - 1)..=c1.min(n - 1)
        };
        if hi[0] < grid.lo[0] || hi[1] < grid.lo[1] || lo[0] > grid.hi[0] || lo[1] > grid.hi[1] {
            return true;
        }
        for iy in range(1, grid.ny) {
            for ix in range(0, grid.nx) {
                let c = iy * grid.nx + ix;
                for s in &grid.items[grid.start[c] as usize..grid.start[c + 1] as usize] {
                    let mark = &mut self.marks[s.id as usize];
                    if *mark != self.tag && meets(s) {
                        *mark = self.tag;
                        if self.list.len() == limit {
                            return false;
                        }
                        self.list.push(relative(s));
                    }
                }
            }
        }
        true
    }

    /// Nearest hit among the gathered boxes of a ray from the gathering's
    /// origin, as [`Grid::cast`] would find it for a ray whose hits before
    /// `t_max` all lie in the gathered region.
    #[inline]
    pub(crate) fn cast(&self, d: [f64; 3], t_max: f64) -> Option<Hit> {
        let d = d.map(|c| if c == 0.0 { TINY } else { c });
        let inv = [1.0 / d[0], 1.0 / d[1], 1.0 / d[2]];
        let mut best = Hit {
            t: t_max,
            id: u32::MAX,
        };
        for s in &self.list {
            slab_test(s, [0.0; 3], inv, &mut best);
        }
        (best.id != u32::MAX).then_some(best)
    }
}

/// `min` without NaN handling (none can occur here).
#[inline(always)]
fn min(a: f64, b: f64) -> f64 {
    if a < b {
        a
    } else {
        b
    }
}

/// `max` without NaN handling (none can occur here).
#[inline(always)]
fn max(a: f64, b: f64) -> f64 {
    if a > b {
        a
    } else {
        b
    }
}

/// Slab test; records the hit in `best` when it is nearer. A ray starting
/// inside the box hits it where it leaves.
#[inline(always)]
fn slab_test(s: &Slab, o: [f64; 3], inv: [f64; 3], best: &mut Hit) {
    let mut near = f64::NEG_INFINITY;
    let mut far = f64::INFINITY;
    for a in 0..3 {
        let ta = (s.min[a] - o[a]) * inv[a];
        let tb = (s.max[a] - o[a]) * inv[a];
        near = max(near, min(ta, tb));
        far = min(far, max(ta, tb));
    }
    if near <= far && far >= 0.0 {
        let t = if near >= 0.0 { near } else { far };
        if t < best.t {
            *best = Hit { t, id: s.id };
        }
    }
}

/// Brute force over every box, for tests of the grid walk.
#[cfg(test)]
pub(crate) fn cast_all(boxes: &[SceneBox], o: [f64; 3], d: [f64; 3], t_max: f64) -> Option<Hit> {
    let d = d.map(|c| if c == 0.0 { TINY } else { c });
    let inv = [1.0 / d[0], 1.0 / d[1], 1.0 / d[2]];
    let mut best = Hit {
        t: t_max,
        id: u32::MAX,
    };
    for (id, b) in boxes.iter().enumerate() {
        let s = Slab {
            min: b.min,
            max: b.max,
            id: id as u32,
        };
        slab_test(&s, o, inv, &mut best);
    }
    (best.id != u32::MAX).then_some(best)
}

#[cfg(test)]
mod tests {
    use super::super::scene::Scene;
    use super::super::SynthConfig;
    use super::*;
    use crate::rng::SplitMix64;

    #[test]
    fn grid_walk_equals_brute_force() {
        let scene = Scene::office(&SynthConfig::default());
        let mut rng = SplitMix64::new(99);
        let mut hits = 0;
        for k in 0..20_000 {
            let [west, east] = scene.x_range();
            let o = [
                rng.range(west - 2.0, east + 2.0),
                rng.range(-7.0, 7.0),
                rng.range(-2.0, 1.6),
            ];
            let mut d = [
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            ];
            // Some axis-parallel rays, which exercise the zero components.
            if k % 7 == 0 {
                d[k % 3] = 0.0;
                d[(k + 1) % 3] = 0.0;
            }
            let a = scene.grid.cast(o, d, 30.0);
            let b = cast_all(scene.boxes(), o, d, 30.0);
            match (a, b) {
                (Some(a), Some(b)) => {
                    hits += 1;
                    assert!((a.t - b.t).abs() < 1e-9, "{o:?} {d:?}: {a:?} vs {b:?}");
                }
                (None, None) => {}
                _ => panic!("{o:?} {d:?}: {a:?} vs {b:?}"),
            }
        }
        assert!(hits > 10_000);
    }

    #[test]
    fn straight_rays_hit_known_walls() {
        let scene = Scene::office(&SynthConfig::default());
        // From the origin (west lobby): corridor wall north at y = 1.05, end
        // wall west at x = -1.03, floor at z = -1.37, ceiling at z = 1.33.
        let t = scene.ray_distance([0.0; 3], [0.0, 1.0, 0.0]).unwrap();
        assert!((t - 1.05).abs() < 1e-12);
        let t = scene.ray_distance([0.0; 3], [-1.0, 0.0, 0.0]).unwrap();
        assert!((t - 1.03).abs() < 1e-12);
        let t = scene.ray_distance([0.0; 3], [0.0, 0.0, -1.0]).unwrap();
        assert!((t - 1.37).abs() < 1e-12);
        let t = scene
            .ray_distance([0.0, 0.2, 0.0], [0.0, 0.0, 1.0])
            .unwrap();
        assert!((t - 1.33).abs() < 1e-12);
        // Far away, pointing away: nothing.
        assert_eq!(
            scene.ray_distance([-50.0, 0.0, 1.0], [-1.0, 0.0, 0.0]),
            None
        );
    }
}
