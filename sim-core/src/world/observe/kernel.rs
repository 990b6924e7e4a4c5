//! One observer's edges (stage 4 of a step, the inner loops): which agents it perceives, its
//! belief update about each ([`Belief::update`], model.md 3), the clearance, `psi`
//! ([`risk::edge_psi`], model.md 4) and the weighted repulsion ([`crate::model::pedestrian::ModelForces::edge_force`],
//! model.md 5). This file only gathers their inputs and stores their outputs; every number of
//! the model comes from those functions.

use std::mem::MaybeUninit;

use super::{disc_radius, ObserveInputs, ObserveWorker, TargetInfo};
use crate::geometry::{self, clearance_and_normal_oriented, Placed, Vec2};
use crate::model::cognition::Belief;
use crate::model::pedestrian::{lane_max, lane_sum};
use crate::model::risk;
use crate::world::store::EdgeSink;
use crate::world::Agents;
use crate::world::Control;

impl ObserveWorker {
    /// Indexes observer `i`'s beliefs of the previous graph by target id (in `stamp`, under a
    /// new epoch, which it returns) and starts fetching them.
    #[inline(always)]
    pub(super) fn index_beliefs(&mut self, inp: &ObserveInputs, i: usize) -> u32 {
        let a = inp.agents;
        let old = inp.old;
        if self.epoch == u32::MAX {
            self.stamp.fill((0, 0));
            self.epoch = 0;
        }
        self.epoch += 1;
        let epoch = self.epoch;
        let s = a.edge_start[i] as usize;
        let range = s..s + a.edge_len[i] as usize;
        for (k, &t) in old.target[range.clone()].iter().enumerate() {
            self.stamp[t as usize] = (epoch, (s + k) as u32);
        }
        // The update reads these beliefs in the new graph's order, at random within the run:
        // ask for their cache lines now (the old graph is megabytes at large N, out of the
        // nearer caches), so that the misses overlap the candidate gather that comes first.
        if range.len() >= PREFETCH_MIN_EDGES {
            prefetch(&old.mu_x[range.clone()]);
            prefetch(&old.mu_y[range.clone()]);
            prefetch(&old.updates[range]);
        }
        epoch
    }

    /// Observer `i`'s edges to its targets `cand` (slots, in grid order), written into `out`
    /// (room for exactly `cand.len()`), and its contact flag, repulsion sum and largest weight
    /// pushed onto the worker's outputs. Its beliefs are indexed under `epoch`.
    #[inline(always)]
    pub(super) fn observer_edges(
        &mut self,
        inp: &ObserveInputs,
        i: usize,
        cand: &[u32],
        epoch: u32,
        out: EdgeSink,
    ) {
        let m = cand.len();
        assert_eq!(out.len(), m);
        if m <= SMALL_OBSERVER_EDGES {
            self.small_observer_edges(inp, i, cand, epoch, out);
            return;
        }
        let a = inp.agents;

        // 3. Targets' state, beliefs, clearances. The edges are written straight into their
        // place in the edge store (no zero-fill or copy first).
        let EdgeSink {
            target: e_target,
            slot: e_slot,
            mu_x: e_mu_x,
            mu_y: e_mu_y,
            updates: e_updates,
            clearance: e_clear,
            psi: e_psi,
            u: e_u,
        } = out;
        // Sliced to `m` so that the compiler knows every length (no bound checks in the loops).
        let (e_target, e_slot) = (&mut e_target[..m], &mut e_slot[..m]);
        let (e_mu_x, e_mu_y, e_updates) = (&mut e_mu_x[..m], &mut e_mu_y[..m], &mut e_updates[..m]);
        let (e_clear, e_psi, e_u) = (&mut e_clear[..m], &mut e_psi[..m], &mut e_u[..m]);
        let alongs = &mut self.along[..m];
        let dists = &mut self.dist[..m];
        let accns = &mut self.accn[..m];
        let vehs = &mut self.veh[..m];
        let nnxs = &mut self.nnx[..m];
        let nnys = &mut self.nny[..m];
        let rects = &mut self.rect[..m];
        let model = inp.params.cognition.prediction;
        let observer = Observer::of(inp, i);
        let mut contact = false;
        for c in 0..m {
            let j = cand[c] as usize;
            let t = &inp.targets[j];
            let st = edge_state(inp, &self.stamp, epoch, model, &observer, t, j);
            contact |= st.clearance <= 0.0;
            e_target[c] = MaybeUninit::new(t.id);
            e_slot[c] = MaybeUninit::new(j as u32);
            e_mu_x[c] = MaybeUninit::new(st.belief.mu.x);
            e_mu_y[c] = MaybeUninit::new(st.belief.mu.y);
            e_updates[c] = MaybeUninit::new(st.belief.updates);
            e_clear[c] = MaybeUninit::new(st.clearance);
            e_u[c] = MaybeUninit::new(st.u);
            alongs[c] = st.along;
            dists[c] = st.dist;
            accns[c] = t.acc_norm;
            vehs[c] = t.veh;
            nnxs[c] = st.normal.x;
            nnys[c] = st.normal.y;
            rects[c] = st.rect;
        }

        // 4. Physical risk (risk::edge_psi) and 5. the social forces on a
        // simulated pedestrian (pedestrian::total_force without the goal term, summed in four
        // interleaved lanes), in one loop over the edges.
        // SAFETY: the loop above wrote every entry of these two (each `c` in `0..m` once), and
        // `MaybeUninit<f64>` has the layout of `f64`.
        let (clears, us) = unsafe {
            (
                &*(&*e_clear as *const [MaybeUninit<f64>] as *const [f64]),
                &*(&*e_u as *const [MaybeUninit<f64>] as *const [f64]),
            )
        };
        let (alongs, dists, accns) = (&self.along[..m], &self.dist[..m], &self.accn[..m]);
        let risk = &inp.params.risk;
        let fc = match a.control[i] {
            Control::Model(model) => inp.forces[model.index()],
            _ => None,
        };
        // Two loops rather than a test per edge: the compiler vectorises each only without it.
        let (force, max_w) = match fc {
            None => {
                for c in 0..m {
                    let (psi, _) = risk::edge_psi(risk, alongs[c], dists[c], accns[c], clears[c]);
                    e_psi[c] = MaybeUninit::new(psi);
                }
                (Vec2::zeros(), 0.0)
            }
            Some(fc) => {
                let vehs = &self.veh[..m];
                let (nnxs, nnys, rects) = (&self.nnx[..m], &self.nny[..m], &self.rect[..m]);
                let fxs = &mut self.fx[..m];
                let fys = &mut self.fy[..m];
                let ws = &mut self.w[..m];
                for c in 0..m {
                    let (psi, inv_dist) =
                        risk::edge_psi(risk, alongs[c], dists[c], accns[c], clears[c]);
                    e_psi[c] = MaybeUninit::new(psi);
                    (fxs[c], fys[c], ws[c]) = fc.edge_force(
                        psi,
                        us[c],
                        vehs[c],
                        inv_dist,
                        (nnxs[c], nnys[c], rects[c]),
                        clears[c],
                    );
                }
                (Vec2::new(lane_sum(fxs), lane_sum(fys)), lane_max(ws))
            }
        };
        self.len.push(m as u32);
        self.contact.push(contact);
        self.force.push(force);
        self.max_w.push(max_w);
    }

    /// Steps 3 to 5 of [`ObserveWorker::observer_edges`] for an observer with at most
    /// [`SMALL_OBSERVER_EDGES`] targets: one loop over the edges instead of three passes over
    /// structure-of-arrays scratch whose set-up costs more than a few edges' work (most
    /// observers of a small scene). Both paths compute each edge with [`edge_state`],
    /// [`risk::edge_psi`] and [`crate::model::pedestrian::ModelForces::edge_force`] and sum with the same lane functions, so the result is
    /// bit-identical to the three passes.
    #[inline(always)]
    fn small_observer_edges(
        &mut self,
        inp: &ObserveInputs,
        i: usize,
        cand: &[u32],
        epoch: u32,
        out: EdgeSink,
    ) {
        let m = cand.len();
        let a = inp.agents;
        let model = inp.params.cognition.prediction;
        let observer = Observer::of(inp, i);
        let fc = match a.control[i] {
            Control::Model(model) => inp.forces[model.index()],
            _ => None,
        };
        let mut fxs = [0.0; SMALL_OBSERVER_EDGES];
        let mut fys = [0.0; SMALL_OBSERVER_EDGES];
        let mut ws = [0.0; SMALL_OBSERVER_EDGES];
        let mut contact = false;
        for c in 0..m {
            let j = cand[c] as usize;
            let t = &inp.targets[j];
            let st = edge_state(inp, &self.stamp, epoch, model, &observer, t, j);
            contact |= st.clearance <= 0.0;
            let (psi, inv_dist) = risk::edge_psi(
                &inp.params.risk,
                st.along,
                st.dist,
                t.acc_norm,
                st.clearance,
            );
            if let Some(fc) = fc {
                (fxs[c], fys[c], ws[c]) = fc.edge_force(
                    psi,
                    st.u,
                    t.veh,
                    inv_dist,
                    (st.normal.x, st.normal.y, st.rect),
                    st.clearance,
                );
            }
            out.target[c] = MaybeUninit::new(t.id);
            out.slot[c] = MaybeUninit::new(j as u32);
            out.mu_x[c] = MaybeUninit::new(st.belief.mu.x);
            out.mu_y[c] = MaybeUninit::new(st.belief.mu.y);
            out.updates[c] = MaybeUninit::new(st.belief.updates);
            out.clearance[c] = MaybeUninit::new(st.clearance);
            out.psi[c] = MaybeUninit::new(psi);
            out.u[c] = MaybeUninit::new(st.u);
        }
        let (force, max_w) = match fc {
            None => (Vec2::zeros(), 0.0),
            Some(_) => (
                Vec2::new(lane_sum(&fxs[..m]), lane_sum(&fys[..m])),
                lane_max(&ws[..m]),
            ),
        };
        self.len.push(m as u32);
        self.contact.push(contact);
        self.force.push(force);
        self.max_w.push(max_w);
    }
}

/// Writes into `cand` the slots of every agent within the perception radius of observer `i`,
/// in grid order; returns how many (`cand` has room for every agent).
#[inline(always)]
pub(in crate::world) fn gather_targets(inp: &ObserveInputs, i: usize, cand: &mut [u32]) -> usize {
    let (slots, gx, gy) = inp.grid.sorted();
    let (ranges, rows) = inp.grid.candidate_ranges(i);
    let xi = inp.agents.pos[i];
    let r2 = inp.r2;
    let mut m = 0;
    for &(lo, hi) in &ranges[..rows] {
        m = gather(
            &gx[lo..hi],
            &gy[lo..hi],
            &slots[lo..hi],
            xi,
            r2,
            i as u32,
            cand,
            m,
        );
    }
    m
}

/// Observers with at most this many targets take [`ObserveWorker::small_observer_edges`].
const SMALL_OBSERVER_EDGES: usize = 4;

/// Appends to `cand[m..]` the slots `slots[k]` other than `i` whose positions `(xs[k], ys[k])`
/// lie within `sqrt(r2)` of `xi`, in order; returns the new count. `cand` has room for every
/// slot (`m + slots.len() <= cand.len()`).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn gather(
    xs: &[f64],
    ys: &[f64],
    slots: &[u32],
    xi: Vec2,
    r2: f64,
    i: u32,
    cand: &mut [u32],
    mut m: usize,
) -> usize {
    for ((&x, &y), &j) in xs.iter().zip(ys).zip(slots) {
        let (dx, dy) = (xi.x - x, xi.y - y);
        let inside = (dx * dx + dy * dy <= r2) & (j != i);
        // Written unconditionally, kept by advancing `m` (m < candidates <= n).
        cand[m] = j;
        m += usize::from(inside);
    }
    m
}

/// The observing agent of an observe pass's edges.
struct Observer {
    placed: Placed,
    /// Disc radius; NaN for a rectangle.
    radius: f64,
    /// [`geometry::axes`] of `placed`.
    axes: (f64, f64),
}

impl Observer {
    #[inline(always)]
    fn of(inp: &ObserveInputs, i: usize) -> Self {
        let a = inp.agents;
        Self {
            placed: Placed {
                shape: a.shape[i],
                position: a.pos[i],
                heading: a.heading[i],
            },
            radius: inp.targets[i].radius,
            axes: inp.axes[i],
        }
    }

    /// Clearance to the agent in slot `j` and the push direction, by the footprints' exact
    /// geometry (what an edge with a rectangle on either side takes).
    #[inline]
    fn footprint_clearance(&self, inp: &ObserveInputs, j: usize) -> (f64, Vec2) {
        let a = inp.agents;
        let placed_j = Placed {
            shape: a.shape[j],
            position: a.pos[j],
            heading: a.heading[j],
        };
        clearance_and_normal_oriented(&self.placed, self.axes, &placed_j, inp.axes[j])
    }
}

/// What an observer learns of one target in step 3 of [`ObserveWorker::observer`].
struct EdgeState {
    /// The updated belief and its uncertainty `u`.
    belief: Belief,
    u: f64,
    /// `v_j . (x_i - x_j)`: the target's velocity along the centre offset.
    along: f64,
    /// Centre distance.
    dist: f64,
    clearance: f64,
    /// The repulsion direction before scaling: the centre offset between two discs (`rect` =
    /// 0), the footprint normal when either is a rectangle (`rect` = 1).
    normal: Vec2,
    rect: f64,
}

/// The belief update, distance and clearance of the edge from `observer` to target `t` in slot
/// `j`. Shared by the three-pass and the small observer paths, so both compute the same bits.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn edge_state(
    inp: &ObserveInputs,
    stamp: &[(u32, u32)],
    epoch: u32,
    model: crate::params::PredictionModel,
    observer: &Observer,
    t: &TargetInfo,
    j: usize,
) -> EdgeState {
    let placed_i = &observer.placed;
    let d = placed_i.position - t.pos;
    let vj = t.vel;
    let (seen, k) = stamp[t.id as usize];
    let (belief, u) = if seen == epoch {
        let mut b = inp.old.belief(k as usize);
        let mu_p = b.predict(model, inp.last_change[j]);
        let u = b.update(mu_p, vj, inp.schedule);
        (b, u)
    } else {
        (Belief::first_sight(vj), 0.0)
    };
    let dist = d.norm();
    let (clearance, normal, rect) = contact(d, dist, observer.radius + t.radius, || {
        observer.footprint_clearance(inp, j)
    });
    EdgeState {
        belief,
        u,
        along: vj.x * d.x + vj.y * d.y,
        dist,
        clearance,
        normal,
        rect,
    }
}

/// Clearance and repulsion direction (before scaling, see [`EdgeState`]) of an edge with centre
/// offset `d` (observer minus target) of length `dist`; `radii` is the sum of the two disc radii,
/// NaN when either footprint is a rectangle, which takes `footprint` (exact clearance and unit
/// normal).
#[inline(always)]
fn contact(
    d: Vec2,
    dist: f64,
    radii: f64,
    footprint: impl FnOnce() -> (f64, Vec2),
) -> (f64, Vec2, f64) {
    if !radii.is_nan() {
        ((dist - radii).max(0.0), d, 0.0)
    } else {
        let (c, n) = footprint();
        (c, n, 1.0)
    }
}

/// The repulsion direction `(nnx, nny, rect)` and `1 / dist` of the edge from slot `i` to slot
/// `j`, exactly as the observe pass computed them for the current state: for a move that sums a
/// pedestrian's repulsions again after agents left (`motion.rs`), with the same
/// [`crate::model::pedestrian::ModelForces::edge_force`].
pub(in crate::world) fn edge_direction(a: &Agents, i: usize, j: usize) -> ((f64, f64, f64), f64) {
    let placed = |k: usize| Placed {
        shape: a.shape[k],
        position: a.pos[k],
        heading: a.heading[k],
    };
    let d = a.pos[i] - a.pos[j];
    let dist = d.norm();
    let radii = disc_radius(a.shape[i]) + disc_radius(a.shape[j]);
    let (_, normal, rect) = contact(d, dist, radii, || {
        clearance_and_normal_oriented(
            &placed(i),
            geometry::axes(a.shape[i], a.heading[i]),
            &placed(j),
            geometry::axes(a.shape[j], a.heading[j]),
        )
    });
    ((normal.x, normal.y, rect), geometry::inv_distance(dist))
}

/// Observers with fewer old edges do not prefetch their beliefs (a short run is a few lines).
const PREFETCH_MIN_EDGES: usize = 32;

/// Asks the CPU to bring the cache lines of `run` into the nearest cache: a hint, which changes
/// no value (and does nothing off x86-64). Not vector code: the one intrinsic the observe pass
/// keeps (docs/BENCHMARKS.md section 1 measures it).
#[inline(always)]
fn prefetch<T>(run: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        let start = run.as_ptr().cast::<i8>();
        for offset in (0..std::mem::size_of_val(run)).step_by(64) {
            // SAFETY: a prefetch never faults and writes nothing; the address lies inside
            // `run` (`offset` is below its size in bytes).
            unsafe {
                std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                    start.add(offset),
                )
            };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = run;
}
