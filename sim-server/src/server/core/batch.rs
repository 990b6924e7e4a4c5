//! `BatchStep`: K envs stepped in lockstep (on several threads when K is large), their reply
//! written straight from reusable step buffers.

use super::{
    bad, decode_batch_step, lock, reply_bytes, write_batch_step_ok, Arc, BatchColumns, BatchEnvRef,
    BatchStep, BatchStepResult, BufMut, Buffers, Env, ErrorCode, ErrorReply, Mode, Mutex,
    MutexGuard, Publication, Response, ServerCore, StepScratch, Watch, PARALLEL_MIN_BATCH,
};

/// Most step buffers kept for reuse between batches (as many as batches ever ran at once; a
/// few is plenty).
const MAX_POOLED_BUFFERS: usize = 8;

impl ServerCore {
    /// `BatchStep`.
    pub fn handle_batch(&self, payload: &[u8], watch: &dyn Watch) -> Response {
        let mut pubs = Vec::new();
        let reply = self
            .batch(payload, watch, &mut pubs)
            .unwrap_or_else(|e| reply_bytes::<BatchStepResult>(Err(e)));
        Response {
            reply,
            pubs,
            realtime_envs: Vec::new(),
        }
    }

    /// Steps a batch and writes its `Reply::Ok(BatchStepResult)` straight from the step
    /// buffers (see [`protocol::wire`]): no owned arrays or per-env infos are built, which
    /// halved the allocations and copies of a large batch.
    fn batch(
        &self,
        payload: &[u8],
        watch: &dyn Watch,
        pubs: &mut Vec<Publication>,
    ) -> Result<Vec<u8>, ErrorReply> {
        let (req, order) = self.checked_batch(payload)?;
        let k = req.env_ids.len();
        let handles = self.lookup_all(&req.env_ids)?;
        // A fair turn among the trainers' batches (module `fair`), charged to the trainer that
        // created the first env; held until the reply is written. Taken before any env is
        // locked, so that waiting never holds an env.
        let trainer = lock(&handles[0]).spec.client_id.clone();
        let _turn = self.turns.acquire(&trainer, k as u64);
        let mut envs = lock_in_order(&handles, &order);
        let (n_ext, m) = check_batch_envs(&envs)?;
        let actions = req
            .checked_action_rows(n_ext as u32)
            .map_err(|e| named_batch_agent(e, &req, &envs, n_ext))?;
        for env in &envs {
            env.check_steppable(true)?;
        }
        let mut buf = self.take_buffers(k, n_ext, m as usize);
        let mut refs: Vec<&mut Env> = envs.iter_mut().map(|g| &mut **g).collect();
        let parts = self.step_chunks(&mut refs, &actions, buf.view(), watch, n_ext);
        drop(refs);
        drop(envs);
        let mut cols = BatchColumns::default();
        for (i, (part, p, r)) in parts.into_iter().enumerate() {
            r?;
            if i == 0 {
                cols = part;
            } else {
                cols.append(part);
            }
            pubs.extend(p);
        }
        let arrays = buf.arrays();
        let mut reply = Vec::with_capacity(
            arrays.data_bytes()
                + 8 * k
                + req.env_ids.iter().map(String::len).sum::<usize>()
                + cols.encoded_bytes(),
        );
        let written = write_batch_step_ok(&mut reply, &req.env_ids, &arrays, &cols);
        self.return_buffers(buf);
        written.map_err(Buffers::err)?;
        Ok(reply)
    }

    /// The decoded request within the limits, and its envs' positions in id order (the order
    /// they are locked in); an env listed twice is refused (it would deadlock the locking).
    fn checked_batch(&self, payload: &[u8]) -> Result<(BatchStep, Vec<usize>), ErrorReply> {
        let req: BatchStep = decode_batch_step(payload).map_err(bad)?;
        let k = req.env_ids.len();
        if k == 0 {
            return Err(bad("env_ids is empty"));
        }
        if k > self.limits.max_batch as usize {
            return Err(ErrorReply::new(
                ErrorCode::LimitExceeded,
                format!(
                    "batch of {k} envs exceeds max_batch {}",
                    self.limits.max_batch
                ),
            ));
        }
        let mut order: Vec<usize> = (0..k).collect();
        order.sort_by(|&a, &b| req.env_ids[a].cmp(&req.env_ids[b]));
        for w in order.windows(2) {
            if req.env_ids[w[0]] == req.env_ids[w[1]] {
                let id = &req.env_ids[w[0]];
                return Err(
                    bad(format!("env id {id:?} listed twice in batch")).with_env(id.clone())
                );
            }
        }
        Ok((req, order))
    }

    /// Steps the batch's envs: large batches on several threads (consecutive chunks of envs,
    /// each writing its own range of the one output buffer), the first chunk on this thread.
    /// One part per chunk, in chunk order.
    fn step_chunks(
        &self,
        envs: &mut [&mut Env],
        actions: &[[f64; 2]],
        out: BufMut<'_>,
        watch: &dyn Watch,
        n_ext: usize,
    ) -> Vec<Part> {
        let k = envs.len();
        let threads = if k >= PARALLEL_MIN_BATCH {
            self.batch_threads.min(k / (PARALLEL_MIN_BATCH / 2)).max(1)
        } else {
            1
        };
        let chunk = k.div_ceil(threads);
        let mut steppers = self.take_steppers(threads);
        let run = |base: usize, envs: &mut [&mut Env], out, scratch: &mut StepScratch| {
            step_chunk(
                envs,
                &actions[base * n_ext..],
                out,
                scratch,
                watch,
                base,
                n_ext,
            )
        };
        let parts = if threads <= 1 {
            vec![run(0, envs, out, &mut steppers[0])]
        } else {
            // The first chunk on this thread, the others on the helper threads, each into its
            // own slot (in chunk order).
            let mut slots: Vec<Option<Part>> = (0..threads).map(|_| None).collect();
            let mut work = envs
                .chunks_mut(chunk)
                .zip((0..k).step_by(chunk))
                .zip(out.chunks(k, chunk))
                .zip(steppers.iter_mut())
                .zip(slots.iter_mut());
            let ((((e0, b0), o0), s0), p0) = work.next().expect("k >= 1");
            let jobs: Vec<Box<dyn FnOnce() + Send + '_>> = work
                .map(|((((e, b), o), s), p)| {
                    Box::new(move || *p = Some(run(b, e, o, s))) as Box<dyn FnOnce() + Send + '_>
                })
                .collect();
            self.helpers.run(jobs, || *p0 = Some(run(b0, e0, o0, s0)));
            slots
                .into_iter()
                .map(|p| {
                    p.unwrap_or_else(|| {
                        let panicked =
                            ErrorReply::new(ErrorCode::Internal, "batch worker panicked");
                        (BatchColumns::default(), Vec::new(), Err(panicked))
                    })
                })
                .collect()
        };
        self.return_steppers(steppers);
        parts
    }

    /// Step buffers for a batch, reusing those of an earlier batch when there are any.
    fn take_buffers(&self, k: usize, n_ext: usize, m: usize) -> Buffers {
        let mut buf = lock(&self.scratch).pop().unwrap_or_default();
        buf.resize(k, n_ext, m);
        buf
    }

    /// A step scratch of an earlier request, or a new one.
    pub(super) fn take_stepper(&self) -> StepScratch {
        lock(&self.steppers).pop().unwrap_or_default()
    }

    /// `n` step scratches for a batch's threads.
    fn take_steppers(&self, n: usize) -> Vec<StepScratch> {
        let mut pool = lock(&self.steppers);
        (0..n).map(|_| pool.pop().unwrap_or_default()).collect()
    }

    pub(super) fn return_steppers(&self, steppers: impl IntoIterator<Item = StepScratch>) {
        let mut pool = lock(&self.steppers);
        // Enough for a few batches at once on every thread.
        let room = (4 * self.batch_threads).saturating_sub(pool.len());
        pool.extend(steppers.into_iter().take(room));
    }

    fn return_buffers(&self, buf: Buffers) {
        let mut pool = lock(&self.scratch);
        // As many as batches ever ran at once; a few is plenty.
        if pool.len() < MAX_POOLED_BUFFERS {
            pool.push(buf);
        }
    }
}

/// One chunk's share of a batch: its envs' columns of the reply, its publications, and the
/// first error of its envs.
type Part = (BatchColumns, Vec<Publication>, Result<(), ErrorReply>);

/// Locks the envs in id order (`order`), so that two batches never wait on each other.
fn lock_in_order<'a>(handles: &'a [Arc<Mutex<Env>>], order: &[usize]) -> Vec<MutexGuard<'a, Env>> {
    let mut guards: Vec<Option<MutexGuard<'_, Env>>> = (0..handles.len()).map(|_| None).collect();
    for &i in order {
        guards[i] = Some(lock(&handles[i]));
    }
    guards.into_iter().map(|g| g.expect("locked")).collect()
}

/// Every env of a batch open, in lockstep and of one shape: its `(n_ext, max_agents)`.
fn check_batch_envs(envs: &[MutexGuard<'_, Env>]) -> Result<(usize, u32), ErrorReply> {
    let (n_ext, m) = (envs[0].spec.n_ext(), envs[0].spec.max_agents);
    for env in envs {
        if env.closed {
            return Err(
                ErrorReply::new(ErrorCode::EnvClosed, "env is closed").with_env(env.id.clone())
            );
        }
        if env.spec.mode != Mode::Lockstep {
            return Err(ErrorReply::new(
                ErrorCode::WrongMode,
                "env is in realtime mode; batch step needs lockstep envs",
            )
            .with_env(env.id.clone()));
        }
        if env.spec.n_ext() != n_ext || env.spec.max_agents != m {
            return Err(ErrorReply::new(
                ErrorCode::WrongShape,
                format!(
                    "batch mixes envs: {} has n_ext {} and max_agents {}, {} has {} and {}",
                    envs[0].id,
                    n_ext,
                    m,
                    env.id,
                    env.spec.n_ext(),
                    env.spec.max_agents
                ),
            )
            .with_env(env.id.clone()));
        }
    }
    Ok((n_ext, m))
}

/// Steps one chunk of a batch (its first env is the batch's `base`-th) into `out`.
fn step_chunk(
    envs: &mut [&mut Env],
    actions: &[[f64; 2]],
    mut out: BufMut<'_>,
    scratch: &mut StepScratch,
    watch: &dyn Watch,
    base: usize,
    n_ext: usize,
) -> Part {
    let mut cols = BatchColumns::with_capacity(base as u32, envs.len(), n_ext);
    let mut pubs = Vec::new();
    for (i, env) in envs.iter_mut().enumerate() {
        let rows = &actions[i * n_ext..(i + 1) * n_ext];
        let slots = &mut out.slots(i);
        let gates = watch.gates(&env.id);
        let meta = match env.step_into(rows, slots, gates, &mut pubs, Some(scratch)) {
            Ok(meta) => meta,
            Err(e) => return (cols, pubs, Err(e)),
        };
        cols.push_env(&BatchEnvRef {
            episode: meta.episode,
            scenario: &meta.scenario,
            step: meta.step,
            t: meta.t,
            action_clipped: env.action_clipped(),
            events: &meta.events,
            metrics: &meta.metrics,
        });
        if meta.reset {
            env.push_reset_columns(&mut cols);
        }
    }
    (cols, pubs, Ok(()))
}

/// A batch's non-finite action error with the agent named as the client named it
/// (`pedestrian_0: actions for env ...`), from the env the error names.
fn named_batch_agent(
    e: ErrorReply,
    req: &BatchStep,
    envs: &[MutexGuard<'_, Env>],
    n_ext: usize,
) -> ErrorReply {
    if e.code != ErrorCode::NonFiniteAction {
        return e;
    }
    let Some(env_id) = e.env_id.as_deref() else {
        return e;
    };
    let Some(row) = req.env_ids.iter().position(|id| id == env_id) else {
        return e;
    };
    let values = req.actions.to_f64_vec();
    let per_env = n_ext * 2;
    let chunk = &values[row * per_env..(row + 1) * per_env];
    let name = chunk.iter().position(|v| !v.is_finite()).and_then(|i| {
        envs.iter()
            .find(|env| env.id == env_id)
            .and_then(|env| env.spec.external_names.get(i / 2).cloned())
    });
    match name {
        Some(name) => {
            let message = format!("{name}: {}", e.message);
            ErrorReply::new(e.code, message).with_env(env_id.to_string())
        }
        None => e,
    }
}
