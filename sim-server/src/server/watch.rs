//! Per-env publication gates: which envs anybody watches, kept in step with the open envs by
//! a publisher per open env and watched topic whose zenoh matching status sets that env's flag.

use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, RwLock, RwLockReadGuard};
use std::time::Duration;

use protocol::{EnvTopic, KeySpace};
use tokio::sync::watch;
use zenoh::pubsub::Publisher;
use zenoh::Session;

use super::core::ServerCore;
use super::env::{Gates, Watch};

/// The topics the server publishes per env, in the order of its gates and flags.
pub(super) const TOPICS: [EnvTopic; 5] = [
    EnvTopic::States,
    EnvTopic::Uncertainty,
    EnvTopic::RiskGraph,
    EnvTopic::Events,
    EnvTopic::Result,
];

/// Per-env publication flags. The topic gates say whether anybody subscribes to a topic of
/// *some* env; a viewer or an observer usually follows one env while a trainer steps hundreds,
/// and publishing all of them costed a batched trainer half its throughput (docs/VIEWER.md).
/// While a topic's gate is open, [`sync_env_watch`] keeps one publisher per open env on
/// `{p}/env/{env_id}/{topic}` whose matching status (zenoh's) sets that env's flag. An env it
/// has not reached yet (created in the last quarter second) publishes, as with topic gates only.
#[derive(Default)]
pub(super) struct EnvWatch {
    pub(super) flags: RwLock<HashMap<String, [Option<Arc<AtomicBool>>; 5]>>,
}

impl EnvWatch {
    /// `ServerInfo::tables` entries: envs with per-env flags, and their publishers.
    pub(super) fn sizes(&self) -> [(&'static str, usize); 2] {
        let flags = self.flags.read().unwrap_or_else(|p| p.into_inner());
        let publishers = flags
            .values()
            .map(|f| f.iter().filter(|x| x.is_some()).count())
            .sum();
        [
            ("watched_envs", flags.len()),
            ("env_publishers", publishers),
        ]
    }
}

/// [`Watch`] of a request: the topic gates of the moment narrowed by [`EnvWatch`].
pub(super) struct NetWatch<'a> {
    pub(super) topics: Gates,
    pub(super) flags: RwLockReadGuard<'a, HashMap<String, [Option<Arc<AtomicBool>>; 5]>>,
}

impl Watch for NetWatch<'_> {
    fn gates(&self, env_id: &str) -> Gates {
        let mut g = self.topics;
        if g == Gates::NONE {
            return g; // nobody watches anything: no per-env lookup on the batch path
        }
        if let Some(flags) = self.flags.get(env_id) {
            let narrow = |open: &mut bool, flag: &Option<Arc<AtomicBool>>| {
                if let Some(f) = flag {
                    *open = *open && f.load(Ordering::Relaxed);
                }
            };
            narrow(&mut g.states, &flags[0]);
            narrow(&mut g.uncertainty, &flags[1]);
            narrow(&mut g.risk_graph, &flags[2]);
            narrow(&mut g.events, &flags[3]);
            narrow(&mut g.result, &flags[4]);
        }
        g
    }
}

/// Keeps [`EnvWatch`] in step with the open envs every quarter second while any topic gate is
/// open: a publisher (and its matching listener) per open env and open topic; all dropped
/// when nobody subscribes to anything.
pub(super) async fn sync_env_watch(
    session: Session,
    core: Arc<ServerCore>,
    keys: KeySpace,
    gates: [Arc<AtomicBool>; 5],
    watch: Arc<EnvWatch>,
    mut stop: watch::Receiver<bool>,
) {
    let mut publishers: HashMap<(String, usize), (Publisher<'static>, Arc<AtomicBool>)> =
        HashMap::new();
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = stop.changed() => break,
        }
        let open_topics: Vec<bool> = gates.iter().map(|g| g.load(Ordering::Relaxed)).collect();
        let envs: HashSet<String> = if open_topics.iter().any(|&o| o) {
            core.open_envs().into_iter().collect()
        } else {
            HashSet::new()
        };
        let before = publishers.len();
        publishers.retain(|(env, t), _| open_topics[*t] && envs.contains(env));
        let mut changed = publishers.len() != before;
        for env in &envs {
            for (t, topic) in TOPICS.iter().enumerate() {
                if !open_topics[t] || publishers.contains_key(&(env.clone(), t)) {
                    continue;
                }
                let Ok(key) = keys.env_topic(env, *topic) else {
                    continue;
                };
                let Ok(publisher) = session.declare_publisher(key).await else {
                    continue;
                };
                let flag = Arc::new(AtomicBool::new(true));
                let f = flag.clone();
                let listening = publisher
                    .matching_listener()
                    .callback(move |s| f.store(s.matching(), Ordering::Relaxed))
                    .background()
                    .await;
                if listening.is_err() {
                    continue; // no listener: keep publishing this env (flag stays absent)
                }
                if let Ok(status) = publisher.matching_status().await {
                    flag.fetch_and(status.matching(), Ordering::Relaxed);
                }
                publishers.insert((env.clone(), t), (publisher, flag));
                changed = true;
            }
        }
        if changed {
            let mut table: HashMap<String, [Option<Arc<AtomicBool>>; 5]> = HashMap::new();
            for ((env, t), (_, flag)) in &publishers {
                table.entry(env.clone()).or_default()[*t] = Some(flag.clone());
            }
            *watch.flags.write().unwrap_or_else(|p| p.into_inner()) = table;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flag(on: bool) -> Option<Arc<AtomicBool>> {
        Some(Arc::new(AtomicBool::new(on)))
    }

    #[test]
    fn an_env_nobody_watches_publishes_nothing_while_a_watched_one_does() {
        let watch = EnvWatch::default();
        watch.flags.write().unwrap().extend([
            (
                "watched".to_string(),
                [flag(true), flag(false), flag(true), flag(true), None],
            ),
            (
                "ignored".to_string(),
                [flag(false), flag(false), flag(false), flag(false), None],
            ),
        ]);
        let net = NetWatch {
            topics: Gates::ALL,
            flags: watch.flags.read().unwrap(),
        };
        let watched = net.gates("watched");
        assert!(watched.states && watched.risk_graph && watched.events);
        assert!(!watched.uncertainty, "a topic nobody watches on this env");
        assert!(
            watched.result,
            "no per-env flag yet: the topic gate decides"
        );
        assert_eq!(
            net.gates("ignored"),
            Gates {
                result: true,
                ..Gates::NONE
            }
        );
        // An env the sync task has not reached yet publishes what the topic gates say.
        assert_eq!(net.gates("new"), Gates::ALL);
    }

    #[test]
    fn a_closed_topic_gate_wins_over_an_env_flag() {
        let watch = EnvWatch::default();
        watch.flags.write().unwrap().insert(
            "e".to_string(),
            [flag(true), flag(true), flag(true), flag(true), flag(true)],
        );
        let net = NetWatch {
            topics: Gates::NONE,
            flags: watch.flags.read().unwrap(),
        };
        assert_eq!(net.gates("e"), Gates::NONE);
    }
}
