//! `sim-server router`: a zenoh router in the `sim-server` binary, so a deployment needs no
//! separately installed `zenohd`.
//!
//! The configuration file is a plain zenoh 1.x configuration (the format of zenoh's
//! `DEFAULT_CONFIG.json5`; see `deploy/router.json5`), with the same `--cfg KEY:VALUE` overrides
//! as `sim-server serve` (`KEY` a `/`-separated path, `VALUE` JSON5). Filled in when absent:
//! `mode: "router"` and multicast scouting off; zenoh's own defaults apply otherwise (a router
//! listens on `tcp/[::]:7447`). A mode other than `"router"` is refused. Authentication
//! (`transport/auth/usrpwd`), TLS listeners and `access_control` are zenoh's and configured there.
//!
//! With `plugins/remote_api` in the configuration (e.g. `--cfg
//! 'plugins/remote_api/websocket_port:"127.0.0.1:10000"'`) the router also runs zenoh's
//! remote-api plugin, linked into this binary (cargo feature `remote-api`, on by default): a
//! WebSocket endpoint through which `@eclipse-zenoh/zenoh-ts` in a browser joins the zenoh
//! network. The browser viewer (viewer/, docs/VIEWER.md) uses it.

use std::future::Future;
use std::path::Path;

use serde_json::{json, Value};

use crate::server::config::{
    load_json5_with_overrides, multicast_scouting_off_unless_set, ConfigError,
};

/// Why the router could not run.
#[derive(Debug, thiserror::Error)]
pub enum RouterError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("zenoh: {0}")]
    Zenoh(String),
    #[error(
        "plugins/remote_api is configured but this sim-server was built without the \
         `remote-api` feature"
    )]
    NoRemoteApi,
}

/// Loads the router's zenoh configuration: a JSON5 file (or `{}`) plus overrides, with
/// `mode: "router"` and multicast scouting off filled in when absent.
pub fn load_config(path: Option<&Path>, overrides: &[String]) -> Result<Value, RouterError> {
    let mut root = load_json5_with_overrides(path, overrides)?;
    fill_defaults(&mut root)?;
    Ok(root)
}

/// Fills `mode` and `scouting/multicast/enabled` when absent; refuses another mode.
pub fn fill_defaults(root: &mut Value) -> Result<(), RouterError> {
    let obj = root
        .as_object_mut()
        .ok_or_else(|| ConfigError::Invalid("the top level must be an object".into()))?;
    let mode = obj.entry("mode").or_insert_with(|| json!("router"));
    if mode.as_str() != Some("router") {
        return Err(ConfigError::Invalid(format!(
            "`sim-server router` runs a zenoh router: mode must be \"router\", not {mode}"
        ))
        .into());
    }
    multicast_scouting_off_unless_set(obj);
    Ok(())
}

/// Opens a zenoh session in router mode from `config` (with the remote-api plugin when
/// `plugins/remote_api` is configured), routes until `shutdown` completes, then closes it.
pub async fn run(config: &Value, shutdown: impl Future<Output = ()>) -> Result<(), RouterError> {
    let zcfg = zenoh::Config::from_json5(&config.to_string())
        .map_err(|e| RouterError::Zenoh(format!("configuration: {e}")))?;
    let zerr = |e: zenoh::Error| RouterError::Zenoh(e.to_string());
    let listen = config
        .pointer("/listen/endpoints")
        .map_or_else(|| "zenoh default".to_string(), ToString::to_string);
    if let Some(ws) = config.pointer("/plugins/remote_api/websocket_port") {
        tracing::info!(websocket = %ws, "starting zenoh's remote-api plugin");
        return run_with_remote_api(zcfg, &listen, shutdown).await;
    }
    if config.pointer("/plugins/remote_api").is_some() {
        return Err(ConfigError::Invalid(
            "plugins/remote_api needs a websocket_port (e.g. \"127.0.0.1:10000\")".into(),
        )
        .into());
    }
    let session = zenoh::open(zcfg).await.map_err(zerr)?;
    tracing::info!(zid = %session.zid(), %listen, "sharedspace zenoh router running");
    shutdown.await;
    tracing::info!("router shutting down");
    session.close().await.map_err(zerr)?;
    Ok(())
}

/// A zenoh runtime with the statically linked remote-api plugin: what `zenohd` does with the
/// plugin as a shared library, without loading one.
#[cfg(feature = "remote-api")]
async fn run_with_remote_api(
    zcfg: zenoh::Config,
    listen: &str,
    shutdown: impl Future<Output = ()>,
) -> Result<(), RouterError> {
    use zenoh::internal::plugins::PluginsManager;
    use zenoh::internal::runtime::RuntimeBuilder;
    use zenoh_plugin_remote_api::RemoteApiPlugin;

    let zerr = |e: zenoh::Error| RouterError::Zenoh(e.to_string());
    let mut plugins = PluginsManager::static_plugins_only();
    plugins.declare_static_plugin::<RemoteApiPlugin, &str>("remote_api", true);
    let mut runtime = RuntimeBuilder::new(zcfg)
        .plugins_manager(plugins)
        .build()
        .await
        .map_err(zerr)?;
    runtime.start().await.map_err(zerr)?;
    tracing::info!(zid = %runtime.zid(), %listen, "sharedspace zenoh router running (remote-api)");
    shutdown.await;
    tracing::info!("router shutting down");
    // Not `runtime.close()`: with the plugin's queryables still declared, zenoh 1.10.2 panics
    // in its routing tables ("Undefined face context") while closing. The process exits next,
    // which is how zenohd ends too.
    drop(runtime);
    Ok(())
}

#[cfg(not(feature = "remote-api"))]
async fn run_with_remote_api(
    _zcfg: zenoh::Config,
    _listen: &str,
    _shutdown: impl Future<Output = ()>,
) -> Result<(), RouterError> {
    Err(RouterError::NoRemoteApi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_and_mode() {
        let c = load_config(None, &[]).unwrap();
        assert_eq!(c["mode"], "router");
        assert_eq!(c["scouting"]["multicast"]["enabled"], false);
        zenoh::Config::from_json5(&c.to_string()).unwrap();
        let e = load_config(None, &["mode:peer".into()]).unwrap_err();
        assert!(e.to_string().contains("router"), "{e}");
    }

    #[test]
    fn a_remote_api_section_without_a_websocket_port_is_refused() {
        let c = load_config(None, &["plugins/remote_api:{}".into()]).unwrap();
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let e = rt.block_on(run(&c, async {})).unwrap_err();
        assert!(e.to_string().contains("websocket_port"), "{e}");
    }

    #[test]
    fn deploy_router_file_parses() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/router.json5");
        let c = load_config(Some(&path), &[]).unwrap();
        assert_eq!(c["mode"], "router");
        zenoh::Config::from_json5(&c.to_string()).unwrap();
    }

    #[test]
    fn deploy_client_files_parse() {
        let deploy = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy");
        let v = load_json5_with_overrides(Some(&deploy.join("trainer.json5")), &[]).unwrap();
        assert_eq!(v["mode"], "client");
        zenoh::Config::from_json5(&v.to_string()).unwrap();
        let c = crate::server::ServerConfig::load(Some(&deploy.join("server-routed.json5")), &[])
            .unwrap();
        let z: Value = serde_json::from_str(&c.zenoh_json()).unwrap();
        assert_eq!(z["mode"], "client");
        assert!(z.get("listen").is_none());
        zenoh::Config::from_json5(&c.zenoh_json()).unwrap();
    }
}
