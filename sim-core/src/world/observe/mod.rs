//! Stage 4 of a step, the observe pass (model.md 3, 4, 5, 6 and 5b steps 1–2): for every
//! observer, its perceived agents, its updated beliefs and uncertainty `u`, the clearances, the
//! risk `psi`, the graph's edges, and (for a simulated pedestrian) the sum of its weighted
//! repulsions, which the next move uses.
//!
//! This file holds the pass as a whole: its inputs, the threads it is split over and the
//! instruction-set variants it is compiled for ([`Kernels`]). One observer's edges are computed in
//! `kernel.rs`, which calls the equation modules for every number it produces.

use std::ops::Range;

use super::store::{EdgeSink, EdgeStore};
use super::{AgentId, Agents, StepScratch, World};
use crate::geometry::{self, Shape, Vec2};
use crate::model::cognition::VarianceSchedule;
use crate::model::pedestrian::ModelForces;
use crate::params::{PedestrianModel, WorldParams};
use crate::scenario::AgentKind;
use crate::support::grid::Grid;

mod kernel;

pub(super) use kernel::edge_direction;
use kernel::gather_targets;

impl World {
    /// Builds beliefs, clearances, risk and the graph for the current state (model.md 5b 1–2),
    /// and the social-force repulsions the next move will use (they depend only on the graph).
    pub(super) fn observe(&mut self, s: &mut StepScratch) {
        let n = self.agents.len();
        let r = self.params.perception_radius;
        s.grid.rebuild(&self.agents.pos, r);
        let a = &self.agents;
        let dt = self.params.dt;
        s.targets.clear();
        s.targets.extend((0..n).map(|j| TargetInfo {
            pos: a.pos[j],
            vel: a.vel[j],
            acc_norm: a.acc[j].norm(),
            radius: disc_radius(a.shape[j]),
            id: a.id[j],
            veh: if a.kind[j] == AgentKind::Vehicle {
                1.0
            } else {
                0.0
            },
        }));
        s.last_change.clear();
        s.last_change.extend(a.prev_acc.iter().map(|&p| p * dt));
        s.axes.clear();
        s.axes
            .extend((0..n).map(|j| geometry::axes(a.shape[j], a.heading[j])));
        let threads = if n >= PARALLEL_MIN_AGENTS {
            self.threads.min(n)
        } else {
            1
        };
        let n_total = self.scenario.agents.len();
        while s.workers.len() < threads {
            s.workers.push(ObserveWorker::new(n_total));
        }
        for w in &mut s.workers[..threads] {
            w.fit_agents(n_total);
        }
        let inputs = ObserveInputs {
            targets: &s.targets,
            last_change: &s.last_change,
            axes: &s.axes,
            agents: &self.agents,
            old: &self.edges,
            grid: &s.grid,
            schedule: &self.schedule,
            params: &self.params,
            r2: r * r,
            kernels: self.kernels,
            forces: PedestrianModel::ALL.map(|m| {
                self.params
                    .pedestrians
                    .for_model(m)
                    .and_then(|p| ModelForces::new(m, p))
            }),
        };
        let workers = &mut s.workers[..threads];
        if threads == 1 {
            workers[0].run(&inputs, 0..n);
        } else {
            // Two parallel halves: the targets of every observer (so that each worker knows
            // where in the store its edges go), then the edges, each worker writing its own
            // run of one store. Copying the workers' stores together instead cost about a
            // fifth of a two-thread step at N = 1 000.
            // Observers split by last step's edge counts (and a fixed cost per observer), so
            // that the workers finish together; any split gives the same bits.
            let weight = |i: usize| u64::from(self.agents.edge_len[i]) + 8;
            let total_weight: u64 = (0..n).map(weight).sum();
            let mut bounds = vec![0; threads + 1];
            let (mut t, mut acc) = (1, 0);
            for i in 0..n {
                acc += weight(i);
                while t < threads && acc * threads as u64 >= total_weight * t as u64 {
                    bounds[t] = i + 1;
                    t += 1;
                }
            }
            // Every bound below `threads` is set by the last observer (`acc` is then the total).
            bounds[threads] = n;
            debug_assert!(bounds.windows(2).all(|b| b[0] <= b[1]));
            let range = |t: usize| bounds[t]..bounds[t + 1];
            let helpers = self
                .helpers
                .as_deref()
                .expect("`set_threads` starts the helpers of a world of several threads");
            let run = |jobs: Vec<Box<dyn FnOnce() + Send + '_>>, here: &mut dyn FnMut()| {
                let ok = helpers.run(jobs, here);
                assert!(ok.iter().all(|&ok| ok), "an observe worker panicked");
            };
            {
                let (first, rest) = workers.split_first_mut().expect("at least one worker");
                let inputs = &inputs;
                let jobs = rest
                    .iter_mut()
                    .enumerate()
                    .map(|(t, w)| {
                        Box::new(move || w.gather_all(inputs, range(t + 1)))
                            as Box<dyn FnOnce() + Send + '_>
                    })
                    .collect();
                run(jobs, &mut || first.gather_all(inputs, range(0)));
            }
            let total: usize = workers.iter().map(|w| w.cands.len()).sum();
            let mut store = std::mem::take(&mut workers[0].edges);
            store.clear_with_capacity(total); // room for `total` and more: no reserve needed
            let mut sink = store.sink(total);
            {
                let (first, rest) = workers.split_first_mut().expect("at least one worker");
                let inputs = &inputs;
                let first_out = sink.split_front(first.cands.len());
                let jobs = rest
                    .iter_mut()
                    .enumerate()
                    .map(|(t, w)| {
                        let out = sink.split_front(w.cands.len());
                        Box::new(move || w.edges_into(inputs, range(t + 1), out))
                            as Box<dyn FnOnce() + Send + '_>
                    })
                    .collect();
                let mut first_out = Some(first_out);
                run(jobs, &mut || {
                    let out = first_out.take().expect("runs once");
                    first.edges_into(inputs, range(0), out)
                });
            }
            // SAFETY: the workers' runs cover the `total` entries (their lengths add up), and
            // each worker wrote every field of every entry of its run (`observer_edges`).
            unsafe { store.commit(total) };
            workers[0].edges = store;
        }
        // The workers' outputs are in observer order.
        std::mem::swap(&mut self.edges, &mut s.workers[0].edges);
        self.rep_force.clear();
        self.rep_max_w.clear();
        self.contact.clear();
        let a = &mut self.agents;
        let mut start = 0u32;
        let mut i = 0;
        for w in &s.workers[..threads] {
            for &len in &w.len {
                a.edge_start[i] = start;
                a.edge_len[i] = len;
                start += len;
                i += 1;
            }
            self.rep_force.extend_from_slice(&w.force);
            self.rep_max_w.extend_from_slice(&w.max_w);
            self.contact.extend_from_slice(&w.contact);
        }
        debug_assert_eq!(i, n);
        debug_assert_eq!(start as usize, self.edges.len());
        self.forces_valid = true;
    }
}

/// The radius of a disc footprint; NaN for a rectangle (so that a sum of two radii is NaN when
/// either footprint is a rectangle).
fn disc_radius(shape: Shape) -> f64 {
    match shape {
        Shape::Disc { radius } => radius,
        Shape::Rect { .. } => f64::NAN,
    }
}

/// Scenes with fewer agents step with the AVX2 variant where the CPU has AVX-512.
#[cfg(target_arch = "x86_64")]
const AVX512_MIN_AGENTS: usize = 32;

/// Scenes with at least this many agents split the observe pass over the threads set by
/// [`World::set_threads`]; smaller ones always run on the caller's thread.
pub const PARALLEL_MIN_AGENTS: usize = 512;

/// What an observer reads of a target, gathered once per observe pass into one record per slot
/// (one cache line and one bounds check per edge instead of one per field).
#[derive(Debug, Clone, Copy, Default)]
#[repr(align(64))]
pub(in crate::world) struct TargetInfo {
    pos: Vec2,
    vel: Vec2,
    acc_norm: f64,
    /// Disc radius; NaN for a rectangle.
    radius: f64,
    /// 1 for a vehicle, 0 for a pedestrian (as the force loop selects on it).
    veh: f64,
    id: AgentId,
}

/// What every observe worker reads: the state, the previous edges (beliefs), the grid.
pub(super) struct ObserveInputs<'a> {
    targets: &'a [TargetInfo],
    /// Each target's last observed change of velocity, by slot.
    last_change: &'a [Vec2],
    /// [`geometry::axes`] by slot.
    axes: &'a [(f64, f64)],
    agents: &'a Agents,
    old: &'a EdgeStore,
    grid: &'a Grid,
    schedule: &'a VarianceSchedule,
    params: &'a WorldParams,
    r2: f64,
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    kernels: Kernels,
    /// Social-force constants per pedestrian model (by [`PedestrianModel::index`]), computed outside the
    /// worker: in memory, the force loop selects between loaded constants (built in the loop,
    /// `-1/B` was folded into one division per edge).
    forces: [Option<ModelForces>; PedestrianModel::ALL.len()],
}

/// Which instruction set the observe pass is compiled for: one portable source, compiled once
/// per variant and chosen at run time. Every variant computes the same bits (no FMA); they
/// differ only in how wide the compiler vectorises the per-edge loops.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kernels {
    /// Baseline instructions of the build target.
    Portable,
    /// AVX2 (x86-64 CPUs that report it at run time): the per-edge loops four lanes wide.
    Avx2,
    /// AVX-512 F, DQ and VL besides AVX2: the per-edge loops eight lanes wide.
    Avx512,
}

impl Kernels {
    /// The widest variant this CPU runs (what a new world uses).
    pub fn detect() -> Self {
        [Kernels::Avx512, Kernels::Avx2]
            .into_iter()
            .find(|k| k.is_available())
            .unwrap_or(Kernels::Portable)
    }

    /// Whether this CPU runs the variant.
    pub fn is_available(self) -> bool {
        match self {
            Kernels::Portable => true,
            #[cfg(target_arch = "x86_64")]
            Kernels::Avx2 => std::is_x86_feature_detected!("avx2"),
            #[cfg(target_arch = "x86_64")]
            Kernels::Avx512 => {
                std::is_x86_feature_detected!("avx2")
                    && std::is_x86_feature_detected!("avx512f")
                    && std::is_x86_feature_detected!("avx512dq")
                    && std::is_x86_feature_detected!("avx512vl")
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// Every variant this CPU runs, narrowest first.
    pub fn available() -> Vec<Self> {
        [Kernels::Portable, Kernels::Avx2, Kernels::Avx512]
            .into_iter()
            .filter(|k| k.is_available())
            .collect()
    }
}

/// [`World::use_kernels`] with a variant this CPU does not run.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("this CPU does not run the {0:?} kernels")]
pub struct KernelsUnavailable(pub Kernels);

/// Scratch and output of one observe worker: it handles a contiguous range of observers.
///
/// Each observer is done in three passes over its edges (`kernel.rs`): a gather of the
/// candidates within the perception radius (branch-free compaction), a pass that reads the
/// targets' state and updates the beliefs ([`crate::model::cognition::Belief::update`]; random access),
/// writing the edges straight into the edge store, and one branch-free loop over
/// structure-of-arrays scratch for the risk ([`crate::model::risk::edge_psi`]) and the social forces
/// ([`crate::model::pedestrian::edge_force`]), which the compiler vectorises. The whole pass is one
/// source compiled three times, portable, AVX2 and AVX-512 ([`Kernels`], chosen at run time).
/// A threaded pass runs in two halves ([`ObserveWorker::gather_all`], then
/// [`ObserveWorker::edges_into`]) so that the workers write into one store.
#[derive(Debug, Clone, Default)]
pub(super) struct ObserveWorker {
    /// `stamp[id].0 == epoch` when the current observer had a belief about agent `id`, held by
    /// edge `stamp[id].1` of the previous graph.
    stamp: Vec<(u32, u32)>,
    epoch: u32,
    /// Slots of the current observer's targets.
    cand: Vec<u32>,
    /// A threaded pass's targets of all the worker's observers, in order, and how many each.
    cands: Vec<u32>,
    counts: Vec<u32>,
    // Per edge of the current observer.
    /// `v_j . (x_i - x_j)`: the target's velocity along the centre offset.
    along: Vec<f64>,
    dist: Vec<f64>,
    accn: Vec<f64>,
    /// 1 when the target is a vehicle.
    veh: Vec<f64>,
    /// The unit vector from the target to the observer (the repulsion direction) is
    /// `(nnx, nny) * (rect + (1 - rect) inv_dist)`: the centre offset over the centre distance
    /// between two discs, the footprint normal (`rect` = 1) when either is a rectangle.
    nnx: Vec<f64>,
    nny: Vec<f64>,
    rect: Vec<f64>,
    fx: Vec<f64>,
    fy: Vec<f64>,
    w: Vec<f64>,
    // Output for the worker's observers, in order.
    pub(super) edges: EdgeStore,
    len: Vec<u32>,
    /// Whether some clearance of the observer's is `<= 0` (a collision event to report).
    contact: Vec<bool>,
    force: Vec<Vec2>,
    max_w: Vec<f64>,
}

impl ObserveWorker {
    pub(super) fn new(n_total: usize) -> Self {
        Self {
            stamp: vec![(0, 0); n_total],
            ..Self::default()
        }
    }

    /// Room in the stamp table for agent ids below `n_total` (a worker shared by worlds of
    /// several sizes). New entries hold epoch 0, which no observer uses.
    fn fit_agents(&mut self, n_total: usize) {
        if self.stamp.len() < n_total {
            self.stamp.resize(n_total, (0, 0));
        }
    }

    /// The whole observe pass of `observers`, into the worker's own edge store.
    fn run(&mut self, inp: &ObserveInputs, observers: Range<usize>) {
        self.dispatch(inp, Phase::Whole(observers));
    }

    /// First half of a threaded pass: the targets of each of `observers`, into `cands` and
    /// `counts` (how many each).
    fn gather_all(&mut self, inp: &ObserveInputs, observers: Range<usize>) {
        self.dispatch(inp, Phase::Gather(observers));
    }

    /// Second half of a threaded pass: the edges of `observers` from the targets
    /// [`ObserveWorker::gather_all`] found, written into `out`, which has room for exactly
    /// them.
    fn edges_into(&mut self, inp: &ObserveInputs, observers: Range<usize>, out: EdgeSink) {
        self.dispatch(inp, Phase::Edges(observers, out));
    }

    fn dispatch(&mut self, inp: &ObserveInputs, phase: Phase) {
        #[cfg(target_arch = "x86_64")]
        match inp.kernels {
            // SAFETY: `Kernels::Avx512` is only chosen where the CPU has these features
            // (`World::use_kernels` checks `Kernels::is_available`; `Kernels::detect`).
            Kernels::Avx512 if inp.agents.len() >= AVX512_MIN_AGENTS => unsafe {
                self.dispatch_avx512(inp, phase)
            },
            // Small scenes run the AVX2 variant even where the CPU has AVX-512: with ten or so
            // edges per observer the eight-lane loops are mostly set-up and remainder.
            // SAFETY: as above; both variants are only chosen where the CPU has AVX2.
            Kernels::Avx2 | Kernels::Avx512 => unsafe { self.dispatch_avx2(inp, phase) },
            Kernels::Portable => self.dispatch_body(inp, phase),
        }
        #[cfg(not(target_arch = "x86_64"))]
        self.dispatch_body(inp, phase);
    }

    /// [`ObserveWorker::dispatch_body`] compiled for AVX2: the compiler vectorises the per-edge
    /// loops four lanes wide. AVX2 alone, no FMA: every operation rounds as in the portable
    /// build, so results are bit-identical.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn dispatch_avx2(&mut self, inp: &ObserveInputs, phase: Phase) {
        self.dispatch_body(inp, phase);
    }

    /// [`ObserveWorker::dispatch_body`] compiled for AVX-512 (F, DQ, VL): the compiler
    /// vectorises the per-edge loops eight lanes wide. No FMA, as in
    /// [`ObserveWorker::dispatch_avx2`].
    ///
    /// # Safety
    /// The CPU must support AVX2, AVX-512F, AVX-512DQ and AVX-512VL.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,avx512f,avx512dq,avx512vl")]
    unsafe fn dispatch_avx512(&mut self, inp: &ObserveInputs, phase: Phase) {
        self.dispatch_body(inp, phase);
    }

    /// The observe pass proper: one source, inlined into (and so compiled for) each
    /// instruction-set variant of `dispatch`.
    #[inline(always)]
    fn dispatch_body(&mut self, inp: &ObserveInputs, phase: Phase) {
        let n = inp.agents.len();
        if self.cand.len() < n {
            self.resize_scratch(n);
        }
        match phase {
            Phase::Whole(observers) => {
                // Room for as many edges as these observers had last step, and some.
                let last: usize = inp.agents.edge_len[observers.clone()]
                    .iter()
                    .map(|&l| l as usize)
                    .sum();
                self.clear_output();
                let mut edges = std::mem::take(&mut self.edges);
                let mut cand = std::mem::take(&mut self.cand);
                edges.clear_with_capacity(last);
                for i in observers {
                    let epoch = self.index_beliefs(inp, i);
                    let m = gather_targets(inp, i, &mut cand);
                    edges.reserve(m);
                    self.observer_edges(inp, i, &cand[..m], epoch, edges.sink(m));
                    // SAFETY: `observer_edges` writes every field of each of the `m` entries.
                    unsafe { edges.commit(m) };
                }
                self.edges = edges;
                self.cand = cand;
            }
            Phase::Gather(observers) => {
                self.cands.clear();
                self.counts.clear();
                for i in observers {
                    let m = gather_targets(inp, i, &mut self.cand);
                    self.cands.extend_from_slice(&self.cand[..m]);
                    self.counts.push(m as u32);
                }
            }
            Phase::Edges(observers, mut out) => {
                assert_eq!(observers.len(), self.counts.len());
                assert_eq!(out.len(), self.cands.len());
                self.clear_output();
                let cands = std::mem::take(&mut self.cands);
                let counts = std::mem::take(&mut self.counts);
                let mut from = 0;
                for (i, &m) in observers.zip(&counts) {
                    let m = m as usize;
                    let epoch = self.index_beliefs(inp, i);
                    let part = out.split_front(m);
                    self.observer_edges(inp, i, &cands[from..from + m], epoch, part);
                    from += m;
                }
                self.cands = cands;
                self.counts = counts;
            }
        }
    }

    fn clear_output(&mut self) {
        self.len.clear();
        self.contact.clear();
        self.force.clear();
        self.max_w.clear();
    }

    /// Sizes the per-edge scratch for at least `n` agents (an observer has fewer than `n` edges;
    /// a worker shared by several worlds keeps the largest size).
    #[cold]
    fn resize_scratch(&mut self, n: usize) {
        self.cand.resize(n, 0);
        for v in [
            &mut self.along,
            &mut self.dist,
            &mut self.accn,
            &mut self.veh,
            &mut self.nnx,
            &mut self.nny,
            &mut self.rect,
            &mut self.fx,
            &mut self.fy,
            &mut self.w,
        ] {
            v.resize(n, 0.0);
        }
    }
}

/// What [`ObserveWorker::dispatch`] does.
enum Phase<'a> {
    /// The whole pass of these observers, into the worker's own store.
    Whole(Range<usize>),
    /// Only their targets ([`ObserveWorker::gather_all`]).
    Gather(Range<usize>),
    /// Their edges from the gathered targets, into this sink ([`ObserveWorker::edges_into`]).
    Edges(Range<usize>, EdgeSink<'a>),
}
