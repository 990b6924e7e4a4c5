//! Episode metrics (model.md 7) and pedestrian-evaluation metrics (model.md 9).

use serde::{Deserialize, Serialize};

use crate::geometry::Vec2;

/// How an agent's episode ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EpisodeStatus {
    Success,
    Collision,
    Timeout,
}

/// The paper's Table II columns for one episode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EpisodeMetrics {
    pub status: EpisodeStatus,
    /// Mean speed over the steps after the start, m/s.
    pub avg_speed: f64,
    /// Mean `|acc_t - acc_{t-1}| / dt` over consecutive transitions, m/s³.
    pub avg_abs_jerk: f64,
    /// Largest `|acc_t|`, m/s².
    pub max_abs_acc: f64,
    /// Number of transitions.
    pub steps: u32,
}

impl EpisodeMetrics {
    /// Metrics from the speed at every step (`speeds[0]` at the start). Accelerations are the
    /// realised `acc_t = (speed_t - speed_{t-1}) / dt`; the jerk needs two of them, so the first
    /// transition has none. The recorded human driver is scored by the same function.
    pub fn from_speeds(status: EpisodeStatus, speeds: &[f64], dt: f64) -> Self {
        let steps = speeds.len().saturating_sub(1);
        let avg_speed = if steps > 0 {
            speeds[1..].iter().sum::<f64>() / steps as f64
        } else {
            0.0
        };
        let accs: Vec<f64> = speeds.windows(2).map(|w| (w[1] - w[0]) / dt).collect();
        let jerks: Vec<f64> = accs
            .windows(2)
            .map(|w| ((w[1] - w[0]) / dt).abs())
            .collect();
        let avg_abs_jerk = if jerks.is_empty() {
            0.0
        } else {
            jerks.iter().sum::<f64>() / jerks.len() as f64
        };
        let max_abs_acc = accs.iter().fold(0.0f64, |m, a| m.max(a.abs()));
        Self {
            status,
            avg_speed,
            avg_abs_jerk,
            max_abs_acc,
            steps: steps as u32,
        }
    }
}

/// Means of episode metrics over a run (the Table II row).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct MetricsSummary {
    pub episodes: u32,
    pub success: f64,
    pub collision: f64,
    pub timeout: f64,
    pub avg_speed: f64,
    pub avg_abs_jerk: f64,
    pub max_abs_acc: f64,
}

impl MetricsSummary {
    pub fn of(episodes: &[EpisodeMetrics]) -> Self {
        let n = episodes.len();
        if n == 0 {
            return Self::default();
        }
        let mean =
            |f: &dyn Fn(&EpisodeMetrics) -> f64| episodes.iter().map(f).sum::<f64>() / n as f64;
        let share = |s: EpisodeStatus| mean(&|m| f64::from(u8::from(m.status == s)));
        Self {
            episodes: n as u32,
            success: share(EpisodeStatus::Success),
            collision: share(EpisodeStatus::Collision),
            timeout: share(EpisodeStatus::Timeout),
            avg_speed: mean(&|m| m.avg_speed),
            avg_abs_jerk: mean(&|m| m.avg_abs_jerk),
            max_abs_acc: mean(&|m| m.max_abs_acc),
        }
    }
}

/// Displacement errors of one episode's simulated pedestrians against their record.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct DisplacementErrors {
    /// Mean over steps `1..=T` and pedestrians of `|x_sim - x_rec|`, m.
    pub ade: f64,
    /// Mean over pedestrians of `|x_sim(T) - x_rec(T)|`, m.
    pub fde: f64,
}

/// ADE and FDE from per-pedestrian trajectories: `sim[p][t]` and `rec[p][t]` for `t = 1..=T`.
pub fn displacement_errors(sim: &[Vec<Vec2>], rec: &[Vec<Vec2>]) -> DisplacementErrors {
    let mut sum = 0.0;
    let mut count = 0usize;
    let mut final_sum = 0.0;
    let mut final_count = 0usize;
    for (s, r) in sim.iter().zip(rec) {
        let len = s.len().min(r.len());
        for t in 0..len {
            sum += (s[t] - r[t]).norm();
            count += 1;
        }
        if len > 0 {
            final_sum += (s[len - 1] - r[len - 1]).norm();
            final_count += 1;
        }
    }
    DisplacementErrors {
        ade: if count > 0 { sum / count as f64 } else { 0.0 },
        fde: if final_count > 0 {
            final_sum / final_count as f64
        } else {
            0.0
        },
    }
}

/// The paper's Table I row: mean ADE, mean FDE and collision rate over episodes.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PedestrianEvalSummary {
    pub episodes: u32,
    pub ade: f64,
    pub fde: f64,
    /// Share of episodes in which a simulated pedestrian collided with anyone.
    pub collision_rate: f64,
}

impl PedestrianEvalSummary {
    pub fn of(episodes: &[(DisplacementErrors, bool)]) -> Self {
        let n = episodes.len();
        if n == 0 {
            return Self::default();
        }
        let nf = n as f64;
        Self {
            episodes: n as u32,
            ade: episodes.iter().map(|e| e.0.ade).sum::<f64>() / nf,
            fde: episodes.iter().map(|e| e.0.fde).sum::<f64>() / nf,
            collision_rate: episodes.iter().filter(|e| e.1).count() as f64 / nf,
        }
    }
}
