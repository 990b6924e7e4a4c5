//! Step 3 of the observe pass (each target's state, the observer's belief update, the
//! clearance) eight edges at a time with AVX-512: the scalar loop of
//! `ObserveWorker::observer_edges` spends most of its time on dependent loads (slot → target →
//! stamp → belief → update constants), which here become gathers of eight lanes each.
//!
//! Every lane does the operations of `edge_state` in the same order, without FMA, so the
//! results are bit-identical to the scalar loop's (the 796-episode dump of
//! `scenarios/examples/step_timing.rs` compares equal, and `tests/threads.rs` compares the
//! kernels). Edges that involve a rectangle take the scalar `Observer::footprint_clearance`
//! lane by lane.

use std::arch::x86_64::*;
use std::mem::{offset_of, size_of, MaybeUninit};

use super::{AgentId, EdgeSink, ObserveInputs, Observer, TargetInfo};
use crate::geometry::Vec2;
use crate::params::PredictionModel;

/// The per-edge columns the risk and force loop reads after step 3 (see `ObserveWorker`).
pub(super) struct StateColumns<'a> {
    pub along: &'a mut [f64],
    pub dist: &'a mut [f64],
    pub accn: &'a mut [f64],
    pub veh: &'a mut [f64],
    pub nnx: &'a mut [f64],
    pub nny: &'a mut [f64],
    pub rect: &'a mut [f64],
    /// Scratch: where each edge's old belief is.
    pub belief_at: &'a mut [u32],
}

// The gathers below address `TargetInfo` fields in units of 8 bytes and the stamp table's
// entries in units of 4.
const TARGET_WORDS: i32 = (size_of::<TargetInfo>() / 8) as i32;
const _: () = assert!(size_of::<TargetInfo>().is_multiple_of(8));
const _: () = assert!(offset_of!(TargetInfo, id).is_multiple_of(4));
const _: () = assert!(size_of::<AgentId>() == 4);
const _: () = assert!(size_of::<(u32, u32)>() == 8);
// A `Vec2` (of `last_change`) is its two coordinates, x first (nalgebra's array storage).
const _: () = assert!(size_of::<Vec2>() == 16);

/// The mask of the first `min(left, 8)` lanes.
#[inline]
fn lanes(left: usize) -> __mmask8 {
    (0xffu16 >> (8 - left.min(8))) as u8
}

/// Panics, naming `what`, unless every lane of `v` in `k` is below `bound` (unsigned): every
/// index these kernels gather or scatter with is checked first.
#[target_feature(enable = "avx512f,avx512vl")]
#[inline]
fn assert_below(k: __mmask8, v: __m256i, bound: __m256i, what: &str) {
    assert!(
        _mm256_mask_cmpge_epu32_mask(k, v, bound) == 0,
        "{what} out of range"
    );
}

/// `stamp` entry fields, as 4-byte offsets.
const STAMP_EPOCH: usize = offset_of!((u32, u32), 0) / 4;
const STAMP_EDGE: usize = offset_of!((u32, u32), 1) / 4;

/// Writes edges `0..cand.len()` of `observer` into `out` and `cols`, as the scalar loop of
/// `observer_edges` does with `edge_state`: target id and slot, the updated belief, `u`, the
/// clearance, and the columns.
/// Returns whether some clearance is `<= 0`.
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512DQ and AVX-512VL. (Every index is checked:
/// slots against the targets, ids against `stamp`, belief indices against the old store.)
#[target_feature(enable = "avx2,avx512f,avx512dq,avx512vl")]
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn edge_states(
    inp: &ObserveInputs,
    stamp: &[(u32, u32)],
    epoch: u32,
    observer: &Observer,
    cand: &[u32],
    out: EdgeSink,
    cols: StateColumns,
) -> bool {
    let m = cand.len();
    assert!(out.len() == m);
    for col in [
        &cols.along,
        &cols.dist,
        &cols.accn,
        &cols.veh,
        &cols.nnx,
        &cols.nny,
        &cols.rect,
    ] {
        assert!(col.len() >= m);
    }
    assert!(cols.belief_at.len() >= m);
    let targets = inp.targets;
    let old = inp.old;
    let (columns, half_inv_s2o) = inp.schedule.update_columns();
    let schedule_len = columns[0].len();
    assert!(schedule_len >= 1 && columns.iter().all(|c| c.len() == schedule_len));
    let constant_acc = inp.params.cognition.prediction == PredictionModel::ConstantAcceleration;

    let tbase = targets.as_ptr().cast::<f64>();
    let field = |offset: usize| tbase.add(offset / 8);
    let (t_px, t_py) = (
        field(offset_of!(TargetInfo, pos)),
        field(offset_of!(TargetInfo, pos) + 8),
    );
    let (t_vx, t_vy) = (
        field(offset_of!(TargetInfo, vel)),
        field(offset_of!(TargetInfo, vel) + 8),
    );
    assert!(inp.last_change.len() == targets.len());
    let (t_lx, t_ly) = (
        inp.last_change.as_ptr().cast::<f64>(),
        inp.last_change.as_ptr().cast::<f64>().add(1),
    );
    let t_acc = field(offset_of!(TargetInfo, acc_norm));
    let t_radius = field(offset_of!(TargetInfo, radius));
    let t_veh = field(offset_of!(TargetInfo, veh));
    let t_id = tbase.cast::<i32>().add(offset_of!(TargetInfo, id) / 4);
    let s_epoch = stamp.as_ptr().cast::<i32>().add(STAMP_EPOCH);
    let s_edge = stamp.as_ptr().cast::<i32>().add(STAMP_EDGE);

    let placed_i = &observer.placed;
    let xi = _mm512_set1_pd(placed_i.position.x);
    let yi = _mm512_set1_pd(placed_i.position.y);
    let r_i = _mm512_set1_pd(observer.radius);
    let h = _mm512_set1_pd(half_inv_s2o);
    let zero = _mm512_setzero_pd();
    let epoch_v = _mm256_set1_epi32(epoch as i32);
    let n_targets = _mm256_set1_epi32(targets.len() as i32);
    let n_stamp = _mm256_set1_epi32(stamp.len() as i32);
    let n_old = _mm256_set1_epi32(old.len() as i32);
    let words = _mm256_set1_epi32(TARGET_WORDS);
    let last_update = _mm256_set1_epi32((schedule_len - 1) as i32);
    // Updates read rows 1.. of the constants (row 0 is a first sight's). Up to 32 such rows (33
    // with the default parameters) are held in registers, four per column, and picked by
    // permutes instead of gathers.
    let in_registers = schedule_len - 1 <= 32;
    let mut rows = [[_mm512_setzero_pd(); 4]; 3];
    if in_registers {
        for (column, regs) in columns.iter().zip(&mut rows) {
            for (q, reg) in regs.iter_mut().enumerate() {
                let from = (1 + 8 * q).min(schedule_len);
                *reg = _mm512_maskz_loadu_pd(lanes(schedule_len - from), column.as_ptr().add(from));
            }
        }
    }
    let sixteen = _mm512_set1_epi64(16);
    let one = _mm256_set1_epi32(1);
    let below_max = _mm256_set1_epi32((u32::MAX - 1) as i32);

    let none = _mm256_set1_epi32(-1);

    // Pass 1: each target's id, and where the observer's belief about it is in the old store
    // (`u32::MAX`: it has none). Its own loop, so that the out-of-order core overlaps the
    // dependent gathers (slot, id, stamp) of several chunks; so does pass 2 with its own.
    let mut o = 0;
    while o < m {
        let k8 = lanes(m - o);
        let j = _mm256_maskz_loadu_epi32(k8, cand.as_ptr().add(o).cast());
        assert_below(k8, j, n_targets, "slot");
        let jw = _mm256_mullo_epi32(j, words);
        let id = _mm256_mmask_i32gather_epi32::<4>(none, k8, _mm256_add_epi32(jw, jw), t_id);
        assert_below(k8, id, n_stamp, "agent id");
        let sid = _mm256_add_epi32(id, id);
        let seen = _mm256_mmask_i32gather_epi32::<4>(none, k8, sid, s_epoch);
        let seen = _mm256_mask_cmpeq_epi32_mask(k8, seen, epoch_v);
        let k = _mm256_mmask_i32gather_epi32::<4>(none, seen, sid, s_edge);
        assert_below(seen, k, n_old, "belief");
        _mm256_mask_storeu_epi32(out.target.as_mut_ptr().add(o).cast(), k8, id);
        _mm256_mask_storeu_epi32(out.slot.as_mut_ptr().add(o).cast(), k8, j);
        _mm256_mask_storeu_epi32(cols.belief_at.as_mut_ptr().add(o).cast(), k8, k);
        o += 8;
    }

    // Pass 2: the belief update, the geometry and the columns.
    let mut contact = false;
    let mut o = 0;
    while o < m {
        let k8 = lanes(m - o);
        // Lanes past `m` read slot 0 (a valid target) and are never stored.
        let j = _mm256_maskz_loadu_epi32(k8, cand.as_ptr().add(o).cast());
        let jw = _mm256_mullo_epi32(j, words);
        // A macro, not a closure: the gathers must be compiled with this function's features.
        macro_rules! gather {
            ($base:expr) => {
                _mm512_i32gather_pd::<8>(jw, $base)
            };
        }
        let k = _mm256_maskz_loadu_epi32(k8, cols.belief_at.as_ptr().add(o).cast());
        let seen = _mm256_mask_cmpneq_epi32_mask(k8, k, none);
        let (px, py) = (gather!(t_px), gather!(t_py));
        let (vx, vy) = (gather!(t_vx), gather!(t_vy));
        let accn = gather!(t_acc);
        let radius_j = gather!(t_radius);
        let veh = gather!(t_veh);
        let mu_x = _mm512_mask_i32gather_pd::<8>(zero, seen, k, old.mu_x.as_ptr());
        let mu_y = _mm512_mask_i32gather_pd::<8>(zero, seen, k, old.mu_y.as_ptr());
        let updates = _mm256_mmask_i32gather_epi32::<4>(
            _mm256_setzero_si256(),
            seen,
            k,
            old.updates.as_ptr().cast(),
        );
        // Belief::predict: `mu + last_change` for the constant-acceleration model once the
        // belief has had an update.
        let (mp_x, mp_y) = if constant_acc {
            let had = _mm256_mask_cmpneq_epi32_mask(seen, updates, _mm256_setzero_si256());
            let j2 = _mm256_add_epi32(j, j);
            (
                // `last_change` is two words per slot.
                _mm512_mask_add_pd(mu_x, had, mu_x, _mm512_i32gather_pd::<8>(j2, t_lx)),
                _mm512_mask_add_pd(mu_y, had, mu_y, _mm512_i32gather_pd::<8>(j2, t_ly)),
            )
        } else {
            (mu_x, mu_y)
        };
        // Belief::update: the constants of update `min(updates + 1, len - 1)` (saturating).
        let next = _mm256_add_epi32(_mm256_min_epu32(updates, below_max), one);
        let row = _mm256_min_epu32(next, last_update);
        let (kl_const, w_prior, w_obs) = if in_registers {
            let r = _mm512_cvtepu32_epi64(_mm256_sub_epi32(row, one));
            let upper = _mm512_test_epi64_mask(r, sixteen);
            macro_rules! pick {
                ($t:expr) => {
                    _mm512_mask_blend_pd(
                        upper,
                        _mm512_permutex2var_pd($t[0], r, $t[1]),
                        _mm512_permutex2var_pd($t[2], r, $t[3]),
                    )
                };
            }
            (pick!(rows[0]), pick!(rows[1]), pick!(rows[2]))
        } else {
            (
                _mm512_i32gather_pd::<8>(row, columns[0].as_ptr()),
                _mm512_i32gather_pd::<8>(row, columns[1].as_ptr()),
                _mm512_i32gather_pd::<8>(row, columns[2].as_ptr()),
            )
        };
        let dfx = _mm512_sub_pd(vx, mp_x);
        let dfy = _mm512_sub_pd(vy, mp_y);
        let sq = _mm512_add_pd(_mm512_mul_pd(dfx, dfx), _mm512_mul_pd(dfy, dfy));
        let u = _mm512_add_pd(kl_const, _mm512_mul_pd(h, sq));
        let new_x = _mm512_add_pd(_mm512_mul_pd(mp_x, w_prior), _mm512_mul_pd(vx, w_obs));
        let new_y = _mm512_add_pd(_mm512_mul_pd(mp_y, w_prior), _mm512_mul_pd(vy, w_obs));
        // First sight: `mu = v`, no updates, `u = 0`.
        let u = _mm512_maskz_mov_pd(seen, u);
        let belief_x = _mm512_mask_blend_pd(seen, vx, new_x);
        let belief_y = _mm512_mask_blend_pd(seen, vy, new_y);
        let belief_updates = _mm256_maskz_mov_epi32(seen, next);

        // Distance, clearance between discs, and `v_j . (x_i - x_j)`.
        let dx = _mm512_sub_pd(xi, px);
        let dy = _mm512_sub_pd(yi, py);
        let dist = _mm512_sqrt_pd(_mm512_add_pd(_mm512_mul_pd(dx, dx), _mm512_mul_pd(dy, dy)));
        let radii = _mm512_add_pd(r_i, radius_j);
        let clearance = _mm512_max_pd(_mm512_sub_pd(dist, radii), zero);
        let along = _mm512_add_pd(_mm512_mul_pd(vx, dx), _mm512_mul_pd(vy, dy));

        macro_rules! store {
            ($dst:expr, $v:expr) => {
                _mm512_mask_storeu_pd(($dst).add(o), k8, $v)
            };
        }
        store!(out.mu_x.as_mut_ptr().cast::<f64>(), belief_x);
        store!(out.mu_y.as_mut_ptr().cast::<f64>(), belief_y);
        _mm256_mask_storeu_epi32(out.updates.as_mut_ptr().add(o).cast(), k8, belief_updates);
        store!(out.clearance.as_mut_ptr().cast::<f64>(), clearance);
        store!(out.u.as_mut_ptr().cast::<f64>(), u);
        store!(cols.along.as_mut_ptr(), along);
        store!(cols.dist.as_mut_ptr(), dist);
        store!(cols.accn.as_mut_ptr(), accn);
        store!(cols.veh.as_mut_ptr(), veh);
        store!(cols.nnx.as_mut_ptr(), dx);
        store!(cols.nny.as_mut_ptr(), dy);
        store!(cols.rect.as_mut_ptr(), zero);

        // `radius_i + radius_j` is NaN where either footprint is a rectangle: those lanes take
        // the exact footprint clearance and normal.
        let rect = _mm512_mask_cmp_pd_mask::<_CMP_UNORD_Q>(k8, radii, radii);
        contact |= _mm512_mask_cmp_pd_mask::<_CMP_LE_OQ>(k8 & !rect, clearance, zero) != 0;
        let mut lanes_left = rect;
        while lanes_left != 0 {
            let c = o + lanes_left.trailing_zeros() as usize;
            lanes_left &= lanes_left - 1;
            let (c_ij, normal) = observer.footprint_clearance(inp, cand[c] as usize);
            contact |= c_ij <= 0.0;
            out.clearance[c] = MaybeUninit::new(c_ij);
            cols.nnx[c] = normal.x;
            cols.nny[c] = normal.y;
            cols.rect[c] = 1.0;
        }
        o += 8;
    }
    contact
}

/// `world::gather` eight candidates at a time: the same distance test (same operations, no
/// FMA), the kept slots of each group packed in order by a compress and stored as one vector.
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512DQ and AVX-512VL.
#[target_feature(enable = "avx2,avx512f,avx512dq,avx512vl")]
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn gather(
    xs: &[f64],
    ys: &[f64],
    slots: &[u32],
    xi: Vec2,
    r2: f64,
    i: u32,
    cand: &mut [u32],
    mut m: usize,
) -> usize {
    let n = slots.len();
    assert!(xs.len() == n && ys.len() == n && m + n <= cand.len());
    let (px, py, pr2) = (
        _mm512_set1_pd(xi.x),
        _mm512_set1_pd(xi.y),
        _mm512_set1_pd(r2),
    );
    let me = _mm256_set1_epi32(i as i32);
    let groups = n / 8;
    for g in 0..groups {
        let o = 8 * g;
        // In bounds: lanes `o..o + 8` of the inputs (`o + 8 <= n`), and the store writes
        // `cand[m..m + 8]` with `m <= m_0 + o` (at most one kept per candidate), so
        // `m + 8 <= m_0 + n <= cand.len()` (asserted above).
        let x = _mm512_loadu_pd(xs.as_ptr().add(o));
        let y = _mm512_loadu_pd(ys.as_ptr().add(o));
        let j = _mm256_loadu_si256(slots.as_ptr().add(o).cast());
        let dx = _mm512_sub_pd(px, x);
        let dy = _mm512_sub_pd(py, y);
        let d2 = _mm512_add_pd(_mm512_mul_pd(dx, dx), _mm512_mul_pd(dy, dy));
        let keep = _mm512_cmp_pd_mask::<_CMP_LE_OQ>(d2, pr2) & _mm256_cmpneq_epi32_mask(j, me);
        let packed = _mm256_maskz_compress_epi32(keep, j);
        _mm256_storeu_si256(cand.as_mut_ptr().add(m).cast(), packed);
        m += keep.count_ones() as usize;
    }
    let o = 8 * groups;
    super::gather(&xs[o..], &ys[o..], &slots[o..], xi, r2, i, cand, m)
}

/// `stamp[targets[k]] = (epoch, first + k)` for every `k`, eight at a time by scatters (in lane
/// order, as the scalar loop of `ObserveWorker::index_beliefs` stores them).
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512DQ and AVX-512VL. (Every target is checked
/// against `stamp`.)
#[target_feature(enable = "avx2,avx512f,avx512dq,avx512vl")]
pub(super) unsafe fn index_stamps(
    targets: &[AgentId],
    first: u32,
    epoch: u32,
    stamp: &mut [(u32, u32)],
) {
    let m = targets.len();
    assert!(u32::try_from(m).is_ok_and(|m| first.checked_add(m).is_some()));
    let n_stamp = _mm256_set1_epi32(stamp.len() as i32);
    // One stamp entry as a 64-bit word: the epoch and the edge index in their fields' halves.
    let epoch_word = _mm512_set1_epi64(i64::from(epoch) << (32 * STAMP_EPOCH));
    let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let base = stamp.as_mut_ptr().cast::<i64>();
    let mut o = 0;
    while o < m {
        let k8 = lanes(m - o);
        let t = _mm256_maskz_loadu_epi32(k8, targets.as_ptr().add(o).cast());
        assert_below(k8, t, n_stamp, "agent id");
        let edge = _mm256_add_epi32(_mm256_set1_epi32((first as usize + o) as i32), lane);
        let edge_word =
            _mm512_slli_epi64::<{ 32 * STAMP_EDGE as u32 }>(_mm512_cvtepu32_epi64(edge));
        let word = _mm512_or_si512(epoch_word, edge_word);
        _mm512_mask_i32scatter_epi64::<8>(base, k8, t, word);
        o += 8;
    }
}
