//! Persistent helper threads that run borrowed jobs beside the calling thread: the server's
//! batch steps (a large batch's chunks) and a threaded [`crate::World`] step (its observe
//! workers).
//!
//! `std::thread::scope` spawns fresh threads for every call: ~50–60 µs of spawn and join on a
//! 2-vCPU VM (and far more system time on some hosts), and each new thread starts on a cold
//! stack, against ~12 µs to hand work to a thread waiting on a channel. A general pool (rayon)
//! was tried and dropped: its idle workers spin before sleeping, and on two cores they took the
//! CPU the zenoh threads need to move the reply (measured in docs/BENCHMARKS.md section 2, in its git history). These helpers
//! block on a channel between jobs. Threads are not I/O: the core stays pure.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{mpsc, Mutex};

/// A job with its borrows erased (see [`Helpers::run`]).
type Task = (Box<dyn FnOnce() + Send + 'static>, mpsc::SyncSender<bool>);

/// `n` threads, job `k` of a [`Helpers::run`] on thread `k`.
#[derive(Debug)]
pub struct Helpers {
    queues: Vec<Mutex<mpsc::Sender<Task>>>,
}

impl Helpers {
    /// `n` helper threads named `{name}-{k}`; fewer if the system refuses to start some (see
    /// [`Helpers::len`]; jobs without a helper run on the calling thread).
    pub fn new(n: usize, name: &str) -> Self {
        let mut queues = Vec::with_capacity(n);
        for k in 0..n {
            let (tx, rx) = mpsc::channel::<Task>();
            let spawned = std::thread::Builder::new()
                .name(format!("{name}-{k}"))
                .spawn(move || {
                    for (job, done) in rx {
                        let ok = catch_unwind(AssertUnwindSafe(job)).is_ok();
                        // The job (and all it borrowed) is gone before `done` is signalled.
                        let _ = done.send(ok);
                    }
                });
            match spawned {
                Ok(_) => queues.push(Mutex::new(tx)),
                Err(_) => break,
            }
        }
        Self { queues }
    }

    /// Number of helper threads.
    pub fn len(&self) -> usize {
        self.queues.len()
    }

    pub fn is_empty(&self) -> bool {
        self.queues.is_empty()
    }

    /// Runs `jobs[k]` on helper `k` (on this thread when there is no helper `k`) and `here` on
    /// this thread, and returns once every one of them has finished: whether each job
    /// completed (false: it panicked). A panic of `here` is resumed after the jobs finished.
    pub fn run<'a>(
        &self,
        jobs: Vec<Box<dyn FnOnce() + Send + 'a>>,
        here: impl FnOnce(),
    ) -> Vec<bool> {
        /// Waits for the submitted jobs however this frame is left: their borrows must not
        /// outlive it.
        struct Pending(Vec<Option<mpsc::Receiver<bool>>>, Vec<bool>);
        impl Pending {
            fn wait(&mut self) {
                for (rx, ok) in self.0.iter_mut().zip(&mut self.1) {
                    if let Some(rx) = rx.take() {
                        // Err: the helper dropped the job unrun (it cannot: it runs every job it
                        // receives), counted as not completed.
                        *ok = rx.recv().unwrap_or(false);
                    }
                }
            }
        }
        impl Drop for Pending {
            fn drop(&mut self) {
                self.wait();
            }
        }
        let mut pending = Pending(Vec::with_capacity(jobs.len()), vec![true; jobs.len()]);
        let mut inline = Vec::new();
        for (k, job) in jobs.into_iter().enumerate() {
            let Some(queue) = self.queues.get(k) else {
                inline.push((k, job));
                pending.0.push(None);
                continue;
            };
            // SAFETY: the job only borrows data that outlives `'a`, which outlives this call;
            // `pending` waits for the job to have run and been dropped (the helper signals
            // only after both) before this frame is left, by return or by unwinding.
            let job: Box<dyn FnOnce() + Send + 'static> = unsafe { std::mem::transmute(job) };
            let (done, rx) = mpsc::sync_channel(1);
            let queue = queue.lock().unwrap_or_else(|p| p.into_inner());
            match queue.send((job, done)) {
                Ok(()) => pending.0.push(Some(rx)),
                Err(mpsc::SendError((job, _))) => {
                    // The helper is gone: run its job here.
                    drop(queue);
                    inline.push((k, job));
                    pending.0.push(None);
                }
            }
        }
        let here = catch_unwind(AssertUnwindSafe(here));
        for (k, job) in inline {
            pending.1[k] = catch_unwind(AssertUnwindSafe(job)).is_ok();
        }
        pending.wait();
        let done = std::mem::take(&mut pending.1);
        if let Err(p) = here {
            std::panic::resume_unwind(p);
        }
        done
    }
}

#[cfg(test)]
mod tests {
    //! The helpers run every job exactly once, with its borrows, and report panics.
    use super::*;
    use std::sync::Arc;

    #[test]
    fn jobs_borrow_and_write_their_own_slots() {
        let h = Helpers::new(2, "t");
        assert_eq!(h.len(), 2);
        for round in 0..50u64 {
            let data: Vec<u64> = (0..300).map(|i| i * round).collect();
            let mut out = [0u64; 3];
            let mut here = 0;
            {
                let (a, rest) = out.split_at_mut(1);
                let (b, c) = rest.split_at_mut(1);
                let d = &data;
                let jobs: Vec<Box<dyn FnOnce() + Send + '_>> = vec![
                    Box::new(move || a[0] = d[..100].iter().sum()),
                    Box::new(move || b[0] = d[100..200].iter().sum()),
                    // More jobs than helpers: the third runs on this thread.
                    Box::new(move || c[0] = d[200..].iter().sum()),
                ];
                let ok = h.run(jobs, || here = d.len());
                assert_eq!(ok, vec![true; 3]);
            }
            assert_eq!(here, 300);
            assert_eq!(out.iter().sum::<u64>(), data.iter().sum::<u64>());
            assert_eq!(out[1], data[100..200].iter().sum::<u64>());
        }
    }

    #[test]
    fn a_panicking_job_is_reported_and_the_helper_keeps_serving() {
        let h = Helpers::new(1, "t");
        let ok = h.run(vec![Box::new(|| panic!("job fails"))], || {});
        assert_eq!(ok, vec![false]);
        let mut x = 0;
        let ok = h.run(vec![Box::new(|| x = 7)], || {});
        assert_eq!((ok, x), (vec![true], 7));
    }

    #[test]
    fn a_panic_here_waits_for_the_jobs_then_resumes() {
        let h = Helpers::new(1, "t");
        let mut x = 0;
        let r = catch_unwind(AssertUnwindSafe(|| {
            h.run(
                vec![Box::new(|| {
                    std::thread::sleep(std::time::Duration::from_millis(20));
                    x = 1;
                })],
                || panic!("here fails"),
            )
        }));
        assert!(r.is_err());
        assert_eq!(x, 1, "the job finished before the panic left run");
    }

    #[test]
    fn callers_on_several_threads_share_the_helpers() {
        let h = Arc::new(Helpers::new(1, "t"));
        let threads: Vec<_> = (0..4)
            .map(|t| {
                let h = h.clone();
                std::thread::spawn(move || {
                    for i in 0..100u64 {
                        let mut v = 0;
                        let ok = h.run(vec![Box::new(|| v = t * 1000 + i)], || {});
                        assert_eq!((ok, v), (vec![true], t * 1000 + i));
                    }
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
    }
}
