//! The step's output buffers: one env's slices of a (possibly batched) result, and the
//! reusable buffers a batch writes into.

use super::{
    BatchArrays, ErrorCode, ErrorReply, F32Array, ObsBatch, ObsRef, U32Array, U8Array, WireTerms,
    N_FEATURES, PAD_NODE_ID,
};

/// Mutable output slices of one env's step (or reset) in row-major layout, one env's share of a
/// (possibly batched) result.
pub struct Slots<'a> {
    pub features: &'a mut [f32],
    pub adjacency: &'a mut [f32],
    pub mask: &'a mut [u8],
    pub node_ids: &'a mut [u32],
    pub reward: &'a mut [f32],
    /// In `REWARD_TERM_NAMES` order.
    pub terms: [&'a mut [f32]; 5],
    pub terminated: &'a mut [u8],
    pub truncated: &'a mut [u8],
}

/// The slots of a contiguous range of envs of a [`Buffers`].
pub struct BufMut<'a> {
    n_ext: usize,
    m: usize,
    s: Slots<'a>,
}

impl<'a> BufMut<'a> {
    /// Per env: features, adjacency, mask/node ids, and per-agent element counts.
    fn sizes(&self) -> [usize; 4] {
        let (n, m, f) = (self.n_ext, self.m, N_FEATURES as usize);
        [n * m * f, n * m * m, n * m, n]
    }

    /// The slots of env `i` of this range.
    pub fn into_slots(self, i: usize) -> Slots<'a> {
        let (_, rest) = self.split_at(i);
        rest.split_at(1).0.s
    }

    /// Splits into envs `[0, i)` and `[i, ..)`.
    pub fn split_at(self, i: usize) -> (BufMut<'a>, BufMut<'a>) {
        let [sf, sa, sm, se] = self.sizes();
        let s = self.s;
        let (f0, f1) = s.features.split_at_mut(i * sf);
        let (a0, a1) = s.adjacency.split_at_mut(i * sa);
        let (m0, m1) = s.mask.split_at_mut(i * sm);
        let (i0, i1) = s.node_ids.split_at_mut(i * sm);
        let (r0, r1) = s.reward.split_at_mut(i * se);
        let [t0, t1, t2, t3, t4] = s.terms.map(|t| t.split_at_mut(i * se));
        let (te0, te1) = s.terminated.split_at_mut(i * se);
        let (tr0, tr1) = s.truncated.split_at_mut(i * se);
        let (n_ext, m) = (self.n_ext, self.m);
        (
            BufMut {
                n_ext,
                m,
                s: Slots {
                    features: f0,
                    adjacency: a0,
                    mask: m0,
                    node_ids: i0,
                    reward: r0,
                    terms: [t0.0, t1.0, t2.0, t3.0, t4.0],
                    terminated: te0,
                    truncated: tr0,
                },
            },
            BufMut {
                n_ext,
                m,
                s: Slots {
                    features: f1,
                    adjacency: a1,
                    mask: m1,
                    node_ids: i1,
                    reward: r1,
                    terms: [t0.1, t1.1, t2.1, t3.1, t4.1],
                    terminated: te1,
                    truncated: tr1,
                },
            },
        )
    }

    /// Splits into consecutive ranges of `chunk` envs (the last may be shorter).
    pub fn chunks(self, k: usize, chunk: usize) -> Vec<BufMut<'a>> {
        let mut out = Vec::with_capacity(k.div_ceil(chunk.max(1)));
        let mut rest = self;
        let mut left = k;
        while left > chunk {
            let (a, b) = rest.split_at(chunk);
            out.push(a);
            rest = b;
            left -= chunk;
        }
        out.push(rest);
        out
    }

    /// Reborrowed slots of env `i` of this range (indexed directly: this runs once per env and
    /// step, where splitting every buffer twice showed in profiles).
    pub fn slots(&mut self, i: usize) -> Slots<'_> {
        let [sf, sa, sm, se] = self.sizes();
        let s = &mut self.s;
        let [t0, t1, t2, t3, t4] = &mut s.terms;
        let r = |n: usize| i * n..(i + 1) * n;
        Slots {
            features: &mut s.features[r(sf)],
            adjacency: &mut s.adjacency[r(sa)],
            mask: &mut s.mask[r(sm)],
            node_ids: &mut s.node_ids[r(sm)],
            reward: &mut s.reward[r(se)],
            terms: [
                &mut t0[r(se)],
                &mut t1[r(se)],
                &mut t2[r(se)],
                &mut t3[r(se)],
                &mut t4[r(se)],
            ],
            terminated: &mut s.terminated[r(se)],
            truncated: &mut s.truncated[r(se)],
        }
    }
}

/// Owned buffers for `k` envs with `n_ext` agents and `m` nodes each.
#[derive(Debug, Clone, Default)]
pub struct Buffers {
    pub k: usize,
    pub n_ext: usize,
    pub m: usize,
    pub features: Vec<f32>,
    pub adjacency: Vec<f32>,
    pub mask: Vec<u8>,
    pub node_ids: Vec<u32>,
    pub reward: Vec<f32>,
    pub terms: [Vec<f32>; 5],
    pub terminated: Vec<u8>,
    pub truncated: Vec<u8>,
}

impl Buffers {
    pub fn new(k: usize, n_ext: usize, m: usize) -> Self {
        let f = N_FEATURES as usize;
        let e = k * n_ext;
        Self {
            k,
            n_ext,
            m,
            features: vec![0.0; e * m * f],
            adjacency: vec![0.0; e * m * m],
            mask: vec![0; e * m],
            node_ids: vec![PAD_NODE_ID; e * m],
            reward: vec![0.0; e],
            terms: std::array::from_fn(|_| vec![0.0; e]),
            terminated: vec![0; e],
            truncated: vec![0; e],
        }
    }

    /// Sizes the buffers for `k` envs with `n_ext` agents and `m` nodes, keeping their
    /// allocations. Contents are unspecified afterwards: every step overwrites all of an env's
    /// slots, so reused buffers need no clearing.
    pub fn resize(&mut self, k: usize, n_ext: usize, m: usize) {
        let f = N_FEATURES as usize;
        let e = k * n_ext;
        self.k = k;
        self.n_ext = n_ext;
        self.m = m;
        self.features.resize(e * m * f, 0.0);
        self.adjacency.resize(e * m * m, 0.0);
        self.mask.resize(e * m, 0);
        self.node_ids.resize(e * m, PAD_NODE_ID);
        self.reward.resize(e, 0.0);
        for t in &mut self.terms {
            t.resize(e, 0.0);
        }
        self.terminated.resize(e, 0);
        self.truncated.resize(e, 0);
    }

    /// Borrowed view of the observation arrays (all envs, stacked).
    pub fn obs_ref(&self) -> ObsRef<'_> {
        ObsRef {
            n_ext: self.n_ext as u32,
            m: self.m as u32,
            features: &self.features,
            adjacency: &self.adjacency,
            mask: &self.mask,
            node_ids: &self.node_ids,
        }
    }

    /// Borrowed view of the arrays for writing a batch reply (see [`protocol::wire`]).
    pub fn arrays(&self) -> BatchArrays<'_> {
        let [t0, t1, t2, t3, t4] = &self.terms;
        BatchArrays {
            k: self.k as u32,
            obs: self.obs_ref(),
            reward: &self.reward,
            terms: [t0, t1, t2, t3, t4],
            terminated: &self.terminated,
            truncated: &self.truncated,
        }
    }

    /// The slots of env `i`.
    pub fn slots(&mut self, i: usize) -> Slots<'_> {
        self.view().into_slots(i)
    }

    /// A mutable view of all envs' slots (splittable into disjoint ranges of envs).
    pub fn view(&mut self) -> BufMut<'_> {
        let [t0, t1, t2, t3, t4] = &mut self.terms;
        BufMut {
            n_ext: self.n_ext,
            m: self.m,
            s: Slots {
                features: &mut self.features,
                adjacency: &mut self.adjacency,
                mask: &mut self.mask,
                node_ids: &mut self.node_ids,
                reward: &mut self.reward,
                terms: [t0, t1, t2, t3, t4],
                terminated: &mut self.terminated,
                truncated: &mut self.truncated,
            },
        }
    }

    fn shape(rest: &[usize]) -> Vec<u32> {
        rest.iter().map(|&d| d as u32).collect()
    }

    pub(crate) fn err(e: protocol::ArrayError) -> ErrorReply {
        ErrorReply::new(ErrorCode::Internal, format!("building arrays: {e}"))
    }

    /// The observation arrays of a one-env buffer (`[n_ext, ...]`; batches are written by
    /// [`protocol::wire`] instead).
    pub fn obs(&self) -> Result<ObsBatch, ErrorReply> {
        let (n, m, f) = (self.n_ext, self.m, N_FEATURES as usize);
        Ok(ObsBatch {
            features: F32Array::new(Self::shape(&[n, m, f]), &self.features).map_err(Self::err)?,
            adjacency: F32Array::new(Self::shape(&[n, m, m]), &self.adjacency)
                .map_err(Self::err)?,
            mask: U8Array::new(Self::shape(&[n, m]), &self.mask).map_err(Self::err)?,
            node_ids: U32Array::new(Self::shape(&[n, m]), &self.node_ids).map_err(Self::err)?,
        })
    }

    /// Reward, terms, terminated, truncated arrays of a one-env buffer (`[n_ext]`).
    pub fn rewards(&self) -> Result<(F32Array, WireTerms, U8Array, U8Array), ErrorReply> {
        let s = Self::shape(&[self.n_ext]);
        let a = |v: &[f32]| F32Array::new(s.clone(), v).map_err(Self::err);
        Ok((
            a(&self.reward)?,
            WireTerms {
                progress: a(&self.terms[0])?,
                success: a(&self.terms[1])?,
                collision: a(&self.terms[2])?,
                danger: a(&self.terms[3])?,
                comfort: a(&self.terms[4])?,
            },
            U8Array::new(s.clone(), &self.terminated).map_err(Self::err)?,
            U8Array::new(s.clone(), &self.truncated).map_err(Self::err)?,
        ))
    }
}
