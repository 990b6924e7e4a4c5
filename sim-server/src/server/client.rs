//! A small Rust client of the protocol (used by the tests and the round-trip benchmark): declares
//! the trainer liveliness token and wraps each request in a zenoh `get` with a timeout.

use std::time::Duration;

use protocol::{
    decode, encode, BatchStep, BatchStepResult, Close, Closed, CreateEnv, EnvCreated, ErrorReply,
    InfoRequest, KeySpace, Reply, Reset, ResetResult, ServerInfo, Step, StepResult,
};
use serde::de::DeserializeOwned;
use serde::Serialize;
use zenoh::liveliness::LivelinessToken;
use zenoh::query::{ConsolidationMode, QueryTarget};
use zenoh::Session;

/// Why a request failed.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("no reply within {0:?}")]
    Timeout(Duration),
    #[error("query ended without a reply")]
    NoReply,
    #[error("zenoh: {0}")]
    Zenoh(String),
    #[error("undecodable reply: {0}")]
    Decode(String),
    #[error("server error: {0}")]
    Server(ErrorReply),
}

impl ClientError {
    /// The server's error reply, if that is what this is.
    pub fn server(&self) -> Option<&ErrorReply> {
        match self {
            ClientError::Server(e) => Some(e),
            _ => None,
        }
    }
}

/// A trainer's connection to one server.
pub struct Client {
    session: Session,
    keys: KeySpace,
    server_id: String,
    client_id: String,
    timeout: Duration,
    token: Option<LivelinessToken>,
}

impl Client {
    /// A client on `session` talking to `server_id`; declares `{p}/trainer/{client_id}`.
    pub async fn new(
        session: Session,
        keys: KeySpace,
        server_id: &str,
        client_id: &str,
    ) -> Result<Self, ClientError> {
        let token = session
            .liveliness()
            .declare_token(
                keys.trainer(client_id)
                    .map_err(|e| ClientError::Zenoh(e.to_string()))?,
            )
            .await
            .map_err(|e| ClientError::Zenoh(e.to_string()))?;
        Ok(Self {
            session,
            keys,
            server_id: server_id.to_string(),
            client_id: client_id.to_string(),
            timeout: Duration::from_secs(10),
            token: Some(token),
        })
    }

    pub fn session(&self) -> &Session {
        &self.session
    }

    pub fn keys(&self) -> &KeySpace {
        &self.keys
    }

    pub fn server_id(&self) -> &str {
        &self.server_id
    }

    pub fn client_id(&self) -> &str {
        &self.client_id
    }

    /// Drops the liveliness token (as a crashed trainer would).
    pub async fn drop_token(&mut self) {
        if let Some(t) = self.token.take() {
            let _ = t.undeclare().await;
        }
    }

    /// Sends `payload` to `key` and returns the raw reply payload.
    pub async fn raw(&self, key: &str, payload: Vec<u8>) -> Result<Vec<u8>, ClientError> {
        raw_get(&self.session, key, payload, self.timeout).await
    }

    /// Sends raw bytes and decodes the reply envelope.
    pub async fn request<T: DeserializeOwned>(
        &self,
        key: &str,
        payload: Vec<u8>,
    ) -> Result<T, ClientError> {
        let bytes = self.raw(key, payload).await?;
        let reply: Reply<T> = decode(&bytes).map_err(|e| ClientError::Decode(e.to_string()))?;
        reply.into_result().map_err(ClientError::Server)
    }

    async fn call<Q: Serialize, T: DeserializeOwned>(
        &self,
        key: Result<String, protocol::ProtocolError>,
        req: &Q,
    ) -> Result<T, ClientError> {
        let key = key.map_err(|e| ClientError::Zenoh(e.to_string()))?;
        self.request(&key, encode(req)).await
    }

    pub async fn info(&self) -> Result<ServerInfo, ClientError> {
        self.call(
            self.keys.server_info(&self.server_id),
            &InfoRequest::default(),
        )
        .await
    }

    /// `CreateEnv` with this client's id filled in.
    pub async fn create(&self, mut req: CreateEnv) -> Result<EnvCreated, ClientError> {
        req.client_id = self.client_id.clone();
        self.call(self.keys.env_create(&self.server_id), &req).await
    }

    pub async fn reset(&self, env_id: &str, req: &Reset) -> Result<ResetResult, ClientError> {
        self.call(self.keys.env_reset(&self.server_id, env_id), req)
            .await
    }

    pub async fn step(&self, env_id: &str, rows: &[[f32; 2]]) -> Result<StepResult, ClientError> {
        self.call(
            self.keys.env_step(&self.server_id, env_id),
            &Step::from_rows(rows),
        )
        .await
    }

    pub async fn batch_step(&self, req: &BatchStep) -> Result<BatchStepResult, ClientError> {
        self.call(self.keys.batch_step(&self.server_id), req).await
    }

    pub async fn close(&self, env_id: &str) -> Result<Closed, ClientError> {
        self.call(self.keys.env_close(&self.server_id, env_id), &Close {})
            .await
    }
}

/// One zenoh `get` with `payload`, returning the first reply's payload (error replies of zenoh
/// itself become [`ClientError::Zenoh`]).
pub async fn raw_get(
    session: &Session,
    key: &str,
    payload: Vec<u8>,
    timeout: Duration,
) -> Result<Vec<u8>, ClientError> {
    let fut = async {
        let replies = session
            .get(key)
            .payload(payload)
            .target(QueryTarget::BestMatching)
            .consolidation(ConsolidationMode::None)
            .timeout(timeout)
            .await
            .map_err(|e| ClientError::Zenoh(e.to_string()))?;
        let reply = replies
            .recv_async()
            .await
            .map_err(|_| ClientError::NoReply)?;
        match reply.result() {
            Ok(sample) => Ok(sample.payload().to_bytes().into_owned()),
            Err(e) => Err(ClientError::Zenoh(format!(
                "error reply: {}",
                String::from_utf8_lossy(&e.payload().to_bytes())
            ))),
        }
    };
    tokio::time::timeout(timeout + Duration::from_secs(1), fut)
        .await
        .map_err(|_| ClientError::Timeout(timeout))?
}
