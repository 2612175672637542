//! The live view's page: one self-contained HTML file (no scripts from
//! elsewhere) that connects to the Foxglove WebSocket and draws every
//! team from above.

use anyhow::Result;
use serde::Serialize;
use serde_json::json;

const VIEWER: &str = include_str!("viewer.html");

/// The page, told the WebSocket's port and the teams (each one's name,
/// robot radius and workspace corners `min` and `max`).
pub fn html(ws_port: u16, teams: &(impl Serialize + ?Sized)) -> Result<String> {
    let config = serde_json::to_string(&json!({ "ws_port": ws_port, "teams": teams }))?;
    Ok(VIEWER.replace("/*CONFIG*/null", &config))
}
