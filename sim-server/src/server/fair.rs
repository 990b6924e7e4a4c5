//! Fair turns for batch work: when more batches wait than may step at once, the next turn goes
//! to the trainer that has been served the least work, so one trainer flooding the server with
//! batches cannot starve another.
//!
//! Start-time fair queueing (Goyal et al., 1996) over trainers, with a batch's cost its number of
//! envs: a batch arriving from trainer `t` gets the start tag `max(finish[t], now)`, where
//! `finish[t]` is the finish tag (start + cost) of `t`'s previous batch and `now` the start tag of
//! the batch granted last; waiting batches are granted in order of (start tag, arrival). A trainer
//! that sends one batch at a time therefore waits behind at most one batch of each other
//! backlogged trainer, however many those have queued; a trainer that was idle does not bank
//! credit. With a single trainer, or fewer waiting batches than slots, nobody waits.

use std::collections::{BTreeSet, HashMap};
use std::sync::{Condvar, Mutex, MutexGuard};

/// At most `slots` batches hold a turn at once; see the module doc for who goes next.
#[derive(Debug)]
pub struct FairTurns {
    slots: usize,
    state: Mutex<State>,
    turn_freed: Condvar,
}

#[derive(Debug, Default)]
struct State {
    /// Turns held now.
    busy: usize,
    /// Start tag of the batch granted last (the queue's virtual time).
    now: u64,
    /// Finish tag of each trainer's latest batch.
    finish: HashMap<String, u64>,
    /// Waiting batches as (start tag, arrival number).
    waiting: BTreeSet<(u64, u64)>,
    arrivals: u64,
}

/// A held turn; dropping it frees the slot.
#[derive(Debug)]
pub struct Turn<'a> {
    turns: &'a FairTurns,
}

impl FairTurns {
    /// Turns for at most `slots` (at least 1) batches at once.
    pub fn new(slots: usize) -> Self {
        Self {
            slots: slots.max(1),
            state: Mutex::new(State::default()),
            turn_freed: Condvar::new(),
        }
    }

    /// How many batches may hold a turn at once.
    pub fn slots(&self) -> usize {
        self.slots
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Waits for a turn for a batch of `cost` envs of `trainer` (blocking this thread).
    pub fn acquire(&self, trainer: &str, cost: u64) -> Turn<'_> {
        let mut st = self.lock();
        let start = st.finish.get(trainer).copied().unwrap_or(0).max(st.now);
        st.finish.insert(trainer.to_string(), start + cost.max(1));
        let ticket = (start, st.arrivals);
        st.arrivals += 1;
        st.waiting.insert(ticket);
        while !(st.busy < self.slots && st.waiting.first() == Some(&ticket)) {
            st = self.turn_freed.wait(st).unwrap_or_else(|p| p.into_inner());
        }
        st.waiting.remove(&ticket);
        st.busy += 1;
        st.now = start;
        drop(st);
        // Another waiting batch may fit in a slot that is still free.
        self.turn_freed.notify_all();
        Turn { turns: self }
    }

    /// Forgets a trainer's finish tag (its envs were reaped); a later batch of the same id
    /// starts from the queue's virtual time like a new trainer's.
    pub fn forget(&self, trainer: &str) {
        self.lock().finish.remove(trainer);
    }

    /// Trainers with a finish tag (each trainer that sent a batch and is not forgotten).
    pub fn trainers(&self) -> usize {
        self.lock().finish.len()
    }

    /// Batches waiting for a turn now.
    pub fn waiting(&self) -> usize {
        self.lock().waiting.len()
    }
}

impl Drop for Turn<'_> {
    fn drop(&mut self) {
        self.turns.lock().busy -= 1;
        self.turns.turn_freed.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::time::{Duration, Instant};

    /// Waits until `n` batches are queued (the threads below have reached `acquire`).
    fn until_waiting(turns: &FairTurns, n: usize) {
        let t0 = Instant::now();
        while turns.waiting() < n {
            assert!(
                t0.elapsed() < Duration::from_secs(10),
                "batches never queued"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    #[test]
    fn a_trainer_with_one_batch_goes_before_a_flooders_queue() {
        let turns = Arc::new(FairTurns::new(1));
        let order = Arc::new(Mutex::new(Vec::new()));
        let held = turns.acquire("flooder", 512); // a batch in progress
        let mut threads = Vec::new();
        for i in 0..6 {
            let (t, o) = (turns.clone(), order.clone());
            threads.push(std::thread::spawn(move || {
                let _turn = t.acquire("flooder", 512);
                o.lock().unwrap().push(format!("flooder-{i}"));
            }));
            until_waiting(&turns, i + 1);
        }
        let (t2, o2) = (turns.clone(), order.clone());
        threads.push(std::thread::spawn(move || {
            let _turn = t2.acquire("small", 8);
            o2.lock().unwrap().push("small".to_string());
        }));
        until_waiting(&turns, 7);
        drop(held);
        for t in threads {
            t.join().unwrap();
        }
        let order = order.lock().unwrap();
        // The small trainer waits behind at most one of the flooder's queued batches.
        let pos = order.iter().position(|s| s == "small").unwrap();
        assert!(
            pos <= 1,
            "small trainer served at position {pos}: {order:?}"
        );
        assert_eq!(order.len(), 7);
    }

    #[test]
    fn a_single_trainer_is_served_in_arrival_order_without_waiting_for_free_slots() {
        let turns = FairTurns::new(2);
        let a = turns.acquire("a", 64);
        let b = turns.acquire("a", 64); // second slot: no wait
        assert_eq!(turns.waiting(), 0);
        drop((a, b));
        let _c = turns.acquire("a", 64);
    }

    #[test]
    fn two_backlogged_trainers_with_equal_batches_alternate() {
        // Two trainers with equal batches queued alternate.
        let turns = Arc::new(FairTurns::new(1));
        let order = Arc::new(Mutex::new(Vec::new()));
        let held = turns.acquire("x", 1);
        let mut threads = Vec::new();
        let mut queued = 0;
        for who in ["a", "a", "a", "b", "b", "b"] {
            let (t, o) = (turns.clone(), order.clone());
            threads.push(std::thread::spawn(move || {
                let _turn = t.acquire(who, 100);
                o.lock().unwrap().push(who);
            }));
            queued += 1;
            until_waiting(&turns, queued);
        }
        drop(held);
        for t in threads {
            t.join().unwrap();
        }
        assert_eq!(*order.lock().unwrap(), vec!["a", "b", "a", "b", "a", "b"]);
    }
}
