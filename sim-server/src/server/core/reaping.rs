//! Trainers' liveliness: the envs of a trainer whose token disappeared, or that never had one,
//! are reaped after their grace.

use super::{lock, Instant, ServerCore};

impl ServerCore {
    /// The liveliness token of `client_id` is present.
    pub fn trainer_alive(&self, client_id: &str) {
        let mut reg = lock(&self.reg);
        let c = reg.clients.entry(client_id.to_string()).or_default();
        c.alive = true;
        c.deadline = None;
    }

    /// The liveliness token of `client_id` disappeared at `now` (closed session, or a link
    /// silent for zenoh's lease): its envs are reaped at once without a `reconnect_grace`,
    /// else when it ends, unless the token reappears first ([`Self::trainer_alive`]).
    /// Returns the envs reaped now.
    pub fn trainer_lost(&self, client_id: &str, now: Instant) -> Vec<String> {
        let grace = self.limits.reconnect_grace;
        if grace.is_zero() {
            return self.trainer_gone(client_id);
        }
        let mut reg = lock(&self.reg);
        if let Some(c) = reg.clients.get_mut(client_id) {
            c.alive = false;
            c.deadline = Some(now + grace);
        }
        Vec::new()
    }

    /// The envs of `client_id` are reaped now. Returns them.
    pub fn trainer_gone(&self, client_id: &str) -> Vec<String> {
        let ids: Vec<String> = {
            let mut reg = lock(&self.reg);
            match reg.clients.remove(client_id) {
                Some(c) => c.envs.into_iter().collect(),
                None => Vec::new(),
            }
        };
        self.turns.forget(client_id);
        self.close_envs(&ids)
    }

    /// Reaps the envs of clients whose grace period ran out without a token. Returns them.
    pub fn sweep(&self, now: Instant) -> Vec<String> {
        let expired: Vec<String> = {
            let reg = lock(&self.reg);
            reg.clients
                .iter()
                .filter(|(_, c)| !c.alive && c.deadline.is_some_and(|d| d <= now))
                .map(|(id, _)| id.clone())
                .collect()
        };
        let mut reaped = Vec::new();
        for c in expired {
            reaped.extend(self.trainer_gone(&c));
        }
        reaped
    }

    /// Closes everything (shutdown).
    pub fn close_all(&self) -> Vec<String> {
        let ids = self.open_envs();
        self.close_envs(&ids)
    }
}
