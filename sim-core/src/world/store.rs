//! The edge store: every observer's belief about each agent it perceives and the risk-graph
//! edge between them, one contiguous run per field, grouped by observer in slot order.

use std::mem::MaybeUninit;

use super::AgentId;
use crate::geometry::Vec2;
use crate::model::cognition::Belief;

/// One directed edge `i -> j` of the risk graph with `i`'s belief about `j` (a copy read out of
/// the [`EdgeStore`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Edge {
    pub target: AgentId,
    /// Slot of the target in the current state.
    pub target_slot: u32,
    pub belief: Belief,
    pub clearance: f64,
    pub psi: f64,
    pub u: f64,
}

/// Every edge of the risk graph, structure of arrays (one entry per edge in each), grouped by
/// observer in slot order. The observe pass writes each field as one contiguous run.
#[derive(Debug, Default)]
pub(super) struct EdgeStore {
    pub(super) target: Vec<AgentId>,
    pub(super) slot: Vec<u32>,
    /// The observer's belief about the target, by field ([`Belief::mu`] and
    /// [`Belief::updates`]): the vectorised observe pass loads and stores each as one run.
    pub(super) mu_x: Vec<f64>,
    pub(super) mu_y: Vec<f64>,
    pub(super) updates: Vec<u32>,
    pub(super) clearance: Vec<f64>,
    pub(super) psi: Vec<f64>,
    pub(super) u: Vec<f64>,
}

/// Room an edge store is given beyond `len` edges when (re)allocated: the graph of the next
/// steps is about as large, and a store that is short must be allocated afresh (megabytes of
/// untouched pages at large `N`).
fn edge_room(len: usize) -> usize {
    len + len / 4 + 64
}

impl Clone for EdgeStore {
    /// A copy with room to grow (see [`edge_room`]), and at least the original's, so that
    /// stepping a cloned world does not reallocate its stores.
    fn clone(&self) -> Self {
        fn copy<T: Copy>(v: &[T], capacity: usize) -> Vec<T> {
            let mut c = Vec::with_capacity(capacity);
            c.extend_from_slice(v);
            c
        }
        let capacity = edge_room(self.len()).max(self.target.capacity());
        Self {
            target: copy(&self.target, capacity),
            slot: copy(&self.slot, capacity),
            mu_x: copy(&self.mu_x, capacity),
            mu_y: copy(&self.mu_y, capacity),
            updates: copy(&self.updates, capacity),
            clearance: copy(&self.clearance, capacity),
            psi: copy(&self.psi, capacity),
            u: copy(&self.u, capacity),
        }
    }
}

impl EdgeStore {
    pub(super) fn len(&self) -> usize {
        self.target.len()
    }

    pub(super) fn clear(&mut self) {
        self.truncate(0);
    }

    pub(super) fn truncate(&mut self, len: usize) {
        self.target.truncate(len);
        self.slot.truncate(len);
        self.mu_x.truncate(len);
        self.mu_y.truncate(len);
        self.updates.truncate(len);
        self.clearance.truncate(len);
        self.psi.truncate(len);
        self.u.truncate(len);
    }

    /// Empties the store and makes room for about `len` edges, and some, without reallocating
    /// (a fresh allocation, not a copy, when the capacity is short: the old contents are dead).
    pub(super) fn clear_with_capacity(&mut self, len: usize) {
        fn fresh<T>(v: &mut Vec<T>, len: usize) {
            v.clear();
            if v.capacity() < len + len / 16 + 64 {
                *v = Vec::with_capacity(edge_room(len));
            }
        }
        fresh(&mut self.target, len);
        fresh(&mut self.slot, len);
        fresh(&mut self.mu_x, len);
        fresh(&mut self.mu_y, len);
        fresh(&mut self.updates, len);
        fresh(&mut self.clearance, len);
        fresh(&mut self.psi, len);
        fresh(&mut self.u, len);
    }

    /// Makes room for `m` more edges in every field.
    pub(super) fn reserve(&mut self, m: usize) {
        self.target.reserve(m);
        self.slot.reserve(m);
        self.mu_x.reserve(m);
        self.mu_y.reserve(m);
        self.updates.reserve(m);
        self.clearance.reserve(m);
        self.psi.reserve(m);
        self.u.reserve(m);
    }

    /// A sink over the next `m` entries of every field's spare capacity (reserve them first).
    pub(super) fn sink(&mut self, m: usize) -> EdgeSink<'_> {
        EdgeSink {
            target: &mut self.target.spare_capacity_mut()[..m],
            slot: &mut self.slot.spare_capacity_mut()[..m],
            mu_x: &mut self.mu_x.spare_capacity_mut()[..m],
            mu_y: &mut self.mu_y.spare_capacity_mut()[..m],
            updates: &mut self.updates.spare_capacity_mut()[..m],
            clearance: &mut self.clearance.spare_capacity_mut()[..m],
            psi: &mut self.psi.spare_capacity_mut()[..m],
            u: &mut self.u.spare_capacity_mut()[..m],
        }
    }

    /// Makes the next `m` entries of every field part of the store.
    ///
    /// # Safety
    /// Those entries must have been written, every field of each (through [`EdgeStore::sink`]).
    pub(super) unsafe fn commit(&mut self, m: usize) {
        let len = self.len() + m;
        // SAFETY: the caller wrote entries `len - m..len` of every field (this function's
        // contract), which lie within each field's capacity (`sink` handed them out of the
        // spare capacity).
        unsafe {
            self.target.set_len(len);
            self.slot.set_len(len);
            self.mu_x.set_len(len);
            self.mu_y.set_len(len);
            self.updates.set_len(len);
            self.clearance.set_len(len);
            self.psi.set_len(len);
            self.u.set_len(len);
        }
    }

    pub(super) fn push(&mut self, e: Edge) {
        self.target.push(e.target);
        self.slot.push(e.target_slot);
        self.mu_x.push(e.belief.mu.x);
        self.mu_y.push(e.belief.mu.y);
        self.updates.push(e.belief.updates);
        self.clearance.push(e.clearance);
        self.psi.push(e.psi);
        self.u.push(e.u);
    }

    #[inline(always)]
    pub(super) fn belief(&self, k: usize) -> Belief {
        Belief {
            mu: Vec2::new(self.mu_x[k], self.mu_y[k]),
            updates: self.updates[k],
        }
    }

    #[inline]
    pub(super) fn get(&self, k: usize) -> Edge {
        Edge {
            target: self.target[k],
            target_slot: self.slot[k],
            belief: self.belief(k),
            clearance: self.clearance[k],
            psi: self.psi[k],
            u: self.u[k],
        }
    }
}

/// Entries of an [`EdgeStore`] still to be written, one run per field, the same length each.
/// The observe pass writes edges through it; a threaded pass splits one sink into disjoint
/// runs, one per worker, so that every worker writes its edges where they belong and none are
/// copied afterwards.
pub(super) struct EdgeSink<'a> {
    pub(super) target: &'a mut [MaybeUninit<AgentId>],
    pub(super) slot: &'a mut [MaybeUninit<u32>],
    pub(super) mu_x: &'a mut [MaybeUninit<f64>],
    pub(super) mu_y: &'a mut [MaybeUninit<f64>],
    pub(super) updates: &'a mut [MaybeUninit<u32>],
    pub(super) clearance: &'a mut [MaybeUninit<f64>],
    pub(super) psi: &'a mut [MaybeUninit<f64>],
    pub(super) u: &'a mut [MaybeUninit<f64>],
}

impl<'a> EdgeSink<'a> {
    pub(super) fn len(&self) -> usize {
        self.target.len()
    }

    /// The first `m` entries as a sink of their own; `self` keeps the rest.
    pub(super) fn split_front(&mut self, m: usize) -> EdgeSink<'a> {
        fn split<'a, T>(v: &mut &'a mut [T], m: usize) -> &'a mut [T] {
            let (front, rest) = std::mem::take(v).split_at_mut(m);
            *v = rest;
            front
        }
        EdgeSink {
            target: split(&mut self.target, m),
            slot: split(&mut self.slot, m),
            mu_x: split(&mut self.mu_x, m),
            mu_y: split(&mut self.mu_y, m),
            updates: split(&mut self.updates, m),
            clearance: split(&mut self.clearance, m),
            psi: split(&mut self.psi, m),
            u: split(&mut self.u, m),
        }
    }
}
