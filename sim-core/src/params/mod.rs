//! Parameter structs. Every field states its unit and its default (model.md; the calibrated
//! pedestrian values replace the section-5 starting values once calibration has run).

use serde::{Deserialize, Serialize};

use crate::geometry::Shape;

mod names;
pub use names::{
    from_fields, merge, pedestrian_param_fields, OverlayError, OTHER_PEDESTRIAN_PARAMS,
    REWARD_WEIGHTS,
};

/// Internal prediction model an observer uses for another agent's next velocity (model.md 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PredictionModel {
    /// `v_hat = mu_post` (default).
    ConstantVelocity,
    /// `v_hat = mu_post + (v_obs(t-1) - v_obs(t-2))`: the last observed change is assumed to persist.
    ConstantAcceleration,
}

/// Cognitive-uncertainty parameters (paper Algorithm 1, model.md section 3).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CognitionParams {
    /// Initial belief standard deviation at first sight, m/s. Default 1.0.
    pub s0: f64,
    /// Process-noise standard deviation added to the prior each step, m/s. Default 0.3.
    pub q: f64,
    /// Observation standard deviation, m/s. Default 0.5.
    pub s_o: f64,
    /// Internal prediction model. Default constant velocity.
    pub prediction: PredictionModel,
}

impl Default for CognitionParams {
    fn default() -> Self {
        Self {
            s0: 1.0,
            q: 0.3,
            s_o: 0.5,
            prediction: PredictionModel::ConstantVelocity,
        }
    }
}

/// Physical-risk and risk-graph parameters (model.md sections 4 and 6).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RiskParams {
    /// Virtual-distance gain `gamma1`, s/m. Default 0.5.
    pub gamma1: f64,
    /// Risk decay `gamma2`, 1/m. Default 1.0.
    pub gamma2: f64,
    /// Weight of uncertainty in the adjacency `A = psi * (1 + lambda * u)`, dimensionless. Default 1.0.
    pub lambda: f64,
}

impl Default for RiskParams {
    fn default() -> Self {
        Self {
            gamma1: 0.5,
            gamma2: 1.0,
            lambda: 1.0,
        }
    }
}

/// Which model moves a pedestrian (model.md section 5).
///
/// **The one list of pedestrian models.** A model is a variant here, a row of [`MODELS`] (its
/// name, label, and how it weighs its forces, which [`crate::model::pedestrian::ModelForces`] reads) and,
/// when it has social forces, a field of [`PedestrianParams`]. Everything else derives its list
/// from these: the wire protocol uses this enum, the CLI and parameter files parse
/// [`PedestrianModel::from_name`], and the Python side reads `clients/src/sharedspace/models.json`,
/// which a test keeps equal to [`models_json`] (docs/ARCHITECTURE.md, "Adding a pedestrian model").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PedestrianModel {
    /// Constant initial velocity vector.
    Cv,
    /// Social force model, all weights 1.
    Sfm,
    /// Risk-aware SFM: weights from physical risk only.
    RaSfm,
    /// Cognitive-risk SFM (the paper's model).
    #[default]
    CrSfm,
    /// Follows its recorded track.
    Replay,
}

/// How a social-force model weighs its forces (model.md 5).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Weighting {
    /// Repulsion weights are `psi` (and the goal force is damped by `exp(-lambda3 max_w)`);
    /// otherwise every weight is 1.
    pub risk: bool,
    /// The weights are `psi (1 + lambda u)` (`lambda1` towards vehicles, `lambda2` towards
    /// pedestrians); requires `risk`.
    pub cognitive: bool,
}

/// One row of [`MODELS`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModelInfo {
    pub model: PedestrianModel,
    /// The name in configs, on the wire and on the command line.
    pub name: &'static str,
    /// The label in tables and figures (the paper's).
    pub label: &'static str,
    /// The social-force weighting; `None` for a model without social forces (and so without
    /// parameters in [`PedestrianParams`]).
    pub weighting: Option<Weighting>,
}

/// Every pedestrian model, in [`PedestrianModel::ALL`] order.
pub const MODELS: [ModelInfo; 5] = [
    ModelInfo {
        model: PedestrianModel::Cv,
        name: "cv",
        label: "CV",
        weighting: None,
    },
    ModelInfo {
        model: PedestrianModel::Sfm,
        name: "sfm",
        label: "SFM",
        weighting: Some(Weighting {
            risk: false,
            cognitive: false,
        }),
    },
    ModelInfo {
        model: PedestrianModel::RaSfm,
        name: "ra_sfm",
        label: "RA-SFM",
        weighting: Some(Weighting {
            risk: true,
            cognitive: false,
        }),
    },
    ModelInfo {
        model: PedestrianModel::CrSfm,
        name: "cr_sfm",
        label: "CR-SFM",
        weighting: Some(Weighting {
            risk: true,
            cognitive: true,
        }),
    },
    ModelInfo {
        model: PedestrianModel::Replay,
        name: "replay",
        label: "Replay",
        weighting: None,
    },
];

impl PedestrianModel {
    pub const ALL: [PedestrianModel; 5] = {
        let mut all = [PedestrianModel::Cv; 5];
        let mut k = 0;
        while k < MODELS.len() {
            all[k] = MODELS[k].model;
            k += 1;
        }
        all
    };

    /// This model's row of [`MODELS`].
    pub fn info(self) -> &'static ModelInfo {
        &MODELS[self.index()]
    }

    /// The model's name as used in configs and on the wire (`cv`, `sfm`, `ra_sfm`, `cr_sfm`, `replay`).
    pub fn name(self) -> &'static str {
        self.info().name
    }

    /// Position of the model in [`Self::ALL`] and [`MODELS`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// Parses a model name; `None` when it is not one of [`Self::name`]'s values.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Every model's name, `", "`-separated and the last after `or` (for messages).
    pub fn names() -> String {
        or_list(&Self::ALL.map(|m| m.name()))
    }
}

/// [`MODELS`] as the JSON document `clients/src/sharedspace/models.json` holds (the Python side's
/// list of models): `{"models": [{"name", "label", "social_force", "risk", "cognitive"}, ...],
/// "default": name, "vehicle_models": [{"name", "label", "reactive"}, ...], "vehicle_default":
/// name}`.
pub fn models_json() -> String {
    let rows: Vec<serde_json::Value> = MODELS
        .iter()
        .map(|m| {
            let w = m.weighting;
            serde_json::json!({
                "name": m.name,
                "label": m.label,
                "social_force": w.is_some(),
                "risk": w.is_some_and(|w| w.risk),
                "cognitive": w.is_some_and(|w| w.cognitive),
            })
        })
        .collect();
    let vehicle_rows: Vec<serde_json::Value> = VEHICLE_MODELS
        .iter()
        .map(|m| serde_json::json!({"name": m.name, "label": m.label, "reactive": m.reactive}))
        .collect();
    let doc = serde_json::json!({
        "models": rows,
        "default": PedestrianModel::default().name(),
        "vehicle_models": vehicle_rows,
        "vehicle_default": VehicleModel::default().name(),
    });
    serde_json::to_string_pretty(&doc).expect("plain JSON") + "\n"
}

/// `a, b or c` (for messages listing the accepted names).
fn or_list(names: &[&str]) -> String {
    let (last, rest) = names.split_last().expect("at least one name");
    format!("{} or {last}", rest.join(", "))
}

/// Which model moves a vehicle nobody controls (docs/MODEL.md, "Traffic").
///
/// **The one list of vehicle models**, as [`PedestrianModel`] is of pedestrian models: a model
/// is a variant here and a row of [`VEHICLE_MODELS`]; the wire, the pool files and the command
/// line parse [`VehicleModel::from_name`], and the Python side reads the list from
/// `clients/src/sharedspace/models.json` ([`models_json`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VehicleModel {
    /// Follows its recorded track, whatever is in its way (the paper's evaluation set-up).
    #[default]
    Replay,
    /// Follows its recorded path and controls its speed along it with the intelligent driver
    /// model: it keeps its record's timing while the road is free, keeps a gap to whatever is in
    /// the corridor ahead, and never drives into it ([`crate::model::traffic`]).
    Idm,
}

/// One row of [`VEHICLE_MODELS`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VehicleModelInfo {
    pub model: VehicleModel,
    /// The name in configs, on the wire and on the command line.
    pub name: &'static str,
    /// The label in tables and figures.
    pub label: &'static str,
    /// Whether the model reacts to the agents around it.
    pub reactive: bool,
}

/// Every vehicle model, in [`VehicleModel::ALL`] order.
pub const VEHICLE_MODELS: [VehicleModelInfo; 2] = [
    VehicleModelInfo {
        model: VehicleModel::Replay,
        name: "replay",
        label: "Replay",
        reactive: false,
    },
    VehicleModelInfo {
        model: VehicleModel::Idm,
        name: "idm",
        label: "IDM",
        reactive: true,
    },
];

impl VehicleModel {
    pub const ALL: [VehicleModel; 2] = [VEHICLE_MODELS[0].model, VEHICLE_MODELS[1].model];

    /// This model's row of [`VEHICLE_MODELS`].
    pub fn info(self) -> &'static VehicleModelInfo {
        &VEHICLE_MODELS[self as usize]
    }

    /// The model's name in configs and on the wire (`replay`, `idm`).
    pub fn name(self) -> &'static str {
        self.info().name
    }

    /// Parses a model name; `None` when it is not one of [`Self::name`]'s values.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Every model's name, `", "`-separated and the last after `or` (for messages).
    pub fn names() -> String {
        or_list(&Self::ALL.map(|m| m.name()))
    }
}

/// Social-force parameters of one pedestrian model (model.md section 5; unit mass, forces in m/s²).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SocialForceParams {
    /// Relaxation time `tau` of the goal force, s. Default 0.5.
    pub tau: f64,
    /// Pedestrian repulsion strength `A_ped`, m/s². Default 2.1.
    pub a_ped: f64,
    /// Pedestrian repulsion range `B_ped`, m. Default 0.3.
    pub b_ped: f64,
    /// Vehicle repulsion strength `A_veh`, m/s². Default 4.0.
    pub a_veh: f64,
    /// Vehicle repulsion range `B_veh`, m. Default 1.0.
    pub b_veh: f64,
    /// Uncertainty gain on vehicle repulsion `lambda1` (cr_sfm), dimensionless. Default 1.0.
    pub lambda1: f64,
    /// Uncertainty gain on pedestrian repulsion `lambda2` (cr_sfm), dimensionless. Default 1.0.
    pub lambda2: f64,
    /// Goal-force damping by the largest repulsion weight `lambda3` (ra_sfm, cr_sfm). Default 1.0.
    pub lambda3: f64,
}

impl Default for SocialForceParams {
    fn default() -> Self {
        Self {
            tau: 0.5,
            a_ped: 2.1,
            b_ped: 0.3,
            a_veh: 4.0,
            b_veh: 1.0,
            lambda1: 1.0,
            lambda2: 1.0,
            lambda3: 1.0,
        }
    }
}

impl SocialForceParams {
    /// The model.md names of the fields, in declaration order ([`SocialForceParams::get_mut`]).
    pub const NAMES: [&'static str; 8] = [
        "tau", "a_ped", "b_ped", "a_veh", "b_veh", "lambda1", "lambda2", "lambda3",
    ];

    /// The field called `name` (one of [`SocialForceParams::NAMES`]).
    pub fn get_mut(&mut self, name: &str) -> Option<&mut f64> {
        Some(match name {
            "tau" => &mut self.tau,
            "a_ped" => &mut self.a_ped,
            "b_ped" => &mut self.b_ped,
            "a_veh" => &mut self.a_veh,
            "b_veh" => &mut self.b_veh,
            "lambda1" => &mut self.lambda1,
            "lambda2" => &mut self.lambda2,
            "lambda3" => &mut self.lambda3,
            _ => return None,
        })
    }
}

impl PedestrianParams {
    /// The parameter sets of every model with social forces (`sfm`, `ra_sfm`, `cr_sfm`).
    pub fn social_force_sets_mut(&mut self) -> [&mut SocialForceParams; 3] {
        [&mut self.sfm, &mut self.ra_sfm, &mut self.cr_sfm]
    }
}

/// Parameters of every pedestrian model, so that agents with different models share one world.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PedestrianParams {
    pub sfm: SocialForceParams,
    pub ra_sfm: SocialForceParams,
    pub cr_sfm: SocialForceParams,
}

impl PedestrianParams {
    /// The social-force parameters used by `model` (`None` for `cv` and `replay`).
    pub fn for_model(&self, model: PedestrianModel) -> Option<&SocialForceParams> {
        match model {
            PedestrianModel::Sfm => Some(&self.sfm),
            PedestrianModel::RaSfm => Some(&self.ra_sfm),
            PedestrianModel::CrSfm => Some(&self.cr_sfm),
            PedestrianModel::Cv | PedestrianModel::Replay => None,
        }
    }
}

/// Vehicle limits and footprint (model.md sections 1 and 2).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VehicleParams {
    /// Footprint. Default rectangle 4.0 m long, 1.8 m wide.
    pub shape: Shape,
    /// Longitudinal acceleration bound, m/s²: actions map onto `[-acc_max, acc_max]`. Default 2.0.
    pub acc_max: f64,
    /// Yaw-rate bound, rad/s: actions map onto `[-omega_max, omega_max]`. Default 0.2.
    pub omega_max: f64,
    /// Maximum speed, m/s (no reversing: minimum 0). Default 6.0.
    pub speed_max: f64,
    /// Goal radius: the vehicle has arrived when its centre is this close to its goal, m. Default 2.0.
    pub goal_radius: f64,
}

impl Default for VehicleParams {
    fn default() -> Self {
        Self {
            shape: Shape::Rect {
                length: 4.0,
                width: 1.8,
            },
            acc_max: 2.0,
            omega_max: 0.2,
            speed_max: 6.0,
            goal_radius: 2.0,
        }
    }
}

/// Parameters of the reactive vehicle model ([`VehicleModel::Idm`], docs/MODEL.md "Traffic").
/// The IDM values are the city-traffic set of Treiber & Kesting, *Traffic Flow Dynamics*
/// (Springer 2013), Table 11.2; the corridor and the look-ahead are ours.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrafficParams {
    /// IDM maximum acceleration `a`, m/s² (capped by `vehicle.acc_max`). Default 1.0.
    pub acc: f64,
    /// IDM comfortable deceleration `b`, m/s². Default 1.5.
    pub comfortable_decel: f64,
    /// IDM time headway `T`, s. Default 1.0.
    pub time_headway: f64,
    /// IDM minimum gap `s0`, m: the gap kept to a standing leader. Default 2.0.
    pub min_gap: f64,
    /// IDM acceleration exponent `delta`, dimensionless. Default 4.0.
    pub exponent: f64,
    /// Lateral margin of the corridor, m: an agent is in the way when the car's footprint, swept
    /// along its path, comes this close to it. Default 0.3.
    pub corridor_margin: f64,
    /// Farthest the corridor reaches ahead along the path, m. Default 40.0.
    pub lookahead_max: f64,
}

impl Default for TrafficParams {
    fn default() -> Self {
        Self {
            acc: 1.0,
            comfortable_decel: 1.5,
            time_headway: 1.0,
            min_gap: 2.0,
            exponent: 4.0,
            corridor_margin: 0.3,
            lookahead_max: 40.0,
        }
    }
}

/// Reward weights (model.md section 7; the paper is silent, these are UAW-PCG-style).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RewardWeights {
    /// Multiplier of progress `d_goal(t-1) - d_goal(t)`, 1/m. Default 1.0.
    pub progress: f64,
    /// Reward on reaching the goal. Default 10.0.
    pub success: f64,
    /// Reward on an AV–pedestrian collision. Default -20.0.
    pub collision: f64,
    /// Danger multiplier: `danger * (c_min - danger_clearance)` when `c_min < danger_clearance`,
    /// 1/m. Default 20.0.
    pub danger: f64,
    /// Clearance below which the danger term applies, m. Default 1.0.
    pub danger_clearance: f64,
    /// Jerk penalty: `-jerk_penalty * jerk²`, s⁶/m². Default 0.05.
    pub jerk_penalty: f64,
    /// Yaw-rate penalty: `-yaw_rate_penalty * omega²`, s²/rad². Default 0.5.
    pub yaw_rate_penalty: f64,
}

impl Default for RewardWeights {
    fn default() -> Self {
        Self {
            progress: 1.0,
            success: 10.0,
            collision: -20.0,
            danger: 20.0,
            danger_clearance: 1.0,
            jerk_penalty: 0.05,
            yaw_rate_penalty: 0.5,
        }
    }
}

/// Everything that parameterises a world. Defaults are model.md's.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorldParams {
    /// Simulation step, s. Default 0.5 (2 Hz); scenarios must be sampled at the same rate.
    pub dt: f64,
    /// Pedestrian disc radius, m. Default 0.3.
    pub ped_radius: f64,
    /// Pedestrian speed cap, m/s. Default 2.0.
    pub ped_speed_max: f64,
    /// Pedestrian goal radius: a simulated pedestrian leaves the scene this close to its goal, m.
    /// Default 0.5.
    pub ped_goal_radius: f64,
    /// Acceleration bound of an externally controlled pedestrian, m/s² per axis of its ego frame.
    /// Default 2.0.
    pub ped_acc_max: f64,
    /// Perception radius `R_perc`, m: beliefs, risk, graph edges and social forces exist only
    /// between agents whose centres are at most this far apart. Default 15.0.
    pub perception_radius: f64,
    /// Time added to the recorded duration to get the episode horizon, s. Default 15.0.
    pub horizon_extra: f64,
    pub vehicle: VehicleParams,
    /// The reactive vehicle model's parameters (vehicles nobody controls, [`VehicleModel::Idm`]).
    pub traffic: TrafficParams,
    pub cognition: CognitionParams,
    pub risk: RiskParams,
    pub pedestrians: PedestrianParams,
    pub reward: RewardWeights,
}

impl Default for WorldParams {
    fn default() -> Self {
        Self {
            dt: 0.5,
            ped_radius: 0.3,
            ped_speed_max: 2.0,
            ped_goal_radius: 0.5,
            ped_acc_max: 2.0,
            perception_radius: 15.0,
            horizon_extra: 15.0,
            vehicle: VehicleParams::default(),
            traffic: TrafficParams::default(),
            cognition: CognitionParams::default(),
            risk: RiskParams::default(),
            pedestrians: PedestrianParams::default(),
            reward: RewardWeights::default(),
        }
    }
}

/// A parameter that is out of its domain.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid parameter `{name}` = {value}: {reason}")]
pub struct ParamError {
    pub name: String,
    pub value: f64,
    pub reason: &'static str,
}

impl WorldParams {
    /// Checks every parameter is finite and in its domain.
    pub fn validate(&self) -> Result<(), ParamError> {
        let check = |name: &str, value: f64, ok: bool, reason: &'static str| {
            if value.is_finite() && ok {
                Ok(())
            } else {
                Err(ParamError {
                    name: name.to_string(),
                    value,
                    reason,
                })
            }
        };
        let positive =
            |name: &str, value: f64| check(name, value, value > 0.0, "must be finite and > 0");
        let non_negative =
            |name: &str, value: f64| check(name, value, value >= 0.0, "must be finite and >= 0");
        let finite = |name: &str, value: f64| check(name, value, true, "must be finite");
        positive("dt", self.dt)?;
        positive("ped_radius", self.ped_radius)?;
        positive("ped_speed_max", self.ped_speed_max)?;
        non_negative("ped_goal_radius", self.ped_goal_radius)?;
        non_negative("ped_acc_max", self.ped_acc_max)?;
        positive("perception_radius", self.perception_radius)?;
        non_negative("horizon_extra", self.horizon_extra)?;
        match self.vehicle.shape {
            Shape::Disc { radius } => positive("vehicle.shape.radius", radius)?,
            Shape::Rect { length, width } => {
                positive("vehicle.shape.length", length)?;
                positive("vehicle.shape.width", width)?;
            }
        }
        non_negative("vehicle.acc_max", self.vehicle.acc_max)?;
        non_negative("vehicle.omega_max", self.vehicle.omega_max)?;
        positive("vehicle.speed_max", self.vehicle.speed_max)?;
        non_negative("vehicle.goal_radius", self.vehicle.goal_radius)?;
        let t = &self.traffic;
        positive("traffic.acc", t.acc)?;
        positive("traffic.comfortable_decel", t.comfortable_decel)?;
        non_negative("traffic.time_headway", t.time_headway)?;
        non_negative("traffic.min_gap", t.min_gap)?;
        positive("traffic.exponent", t.exponent)?;
        non_negative("traffic.corridor_margin", t.corridor_margin)?;
        positive("traffic.lookahead_max", t.lookahead_max)?;
        positive("cognition.s0", self.cognition.s0)?;
        non_negative("cognition.q", self.cognition.q)?;
        positive("cognition.s_o", self.cognition.s_o)?;
        finite("risk.gamma1", self.risk.gamma1)?;
        non_negative("risk.gamma2", self.risk.gamma2)?;
        finite("risk.lambda", self.risk.lambda)?;
        for (prefix, p) in [
            ("sfm", &self.pedestrians.sfm),
            ("ra_sfm", &self.pedestrians.ra_sfm),
            ("cr_sfm", &self.pedestrians.cr_sfm),
        ] {
            let name = |field: &str| format!("pedestrians.{prefix}.{field}");
            positive(&name("tau"), p.tau)?;
            finite(&name("a_ped"), p.a_ped)?;
            positive(&name("b_ped"), p.b_ped)?;
            finite(&name("a_veh"), p.a_veh)?;
            positive(&name("b_veh"), p.b_veh)?;
            finite(&name("lambda1"), p.lambda1)?;
            finite(&name("lambda2"), p.lambda2)?;
            finite(&name("lambda3"), p.lambda3)?;
        }
        let r = &self.reward;
        for (name, v) in [
            ("reward.progress", r.progress),
            ("reward.success", r.success),
            ("reward.collision", r.collision),
            ("reward.danger", r.danger),
            ("reward.danger_clearance", r.danger_clearance),
            ("reward.jerk_penalty", r.jerk_penalty),
            ("reward.yaw_rate_penalty", r.yaw_rate_penalty),
        ] {
            finite(name, v)?;
        }
        Ok(())
    }
}
