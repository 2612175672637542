//! Recordings and the live view: a watcher of each team's traffic (the
//! snapshots its controller publishes, the answers the daemon gives, on
//! iceoryx2 like any other viewer) that logs it to a Foxglove context with
//! two kinds of sink:
//!
//! - `--record FILE.mcap`: an MCAP file (uncompressed; a new file, never
//!   overwritten);
//! - `--live ADDR`: a page at `http://ADDR/` that draws the robots, plans,
//!   obstacles and statuses in a browser (no internet needed: the page is
//!   served from here), fed by a Foxglove WebSocket server on the next port
//!   (`ws://HOST:PORT+1`, protocol `foxglove.sdk.v1`), which the Foxglove
//!   app can open too.
//!
//! Per team, three channels: `/flowopt/TEAM/snapshot` and
//! `/flowopt/TEAM/answer` (JSON, [`flowopt_client::records`]) and `/flowopt/TEAM/scene`
//! (`foxglove.SceneUpdate`, [`scene`]). docs/RECORDING.md gives the
//! layout and how to read it back.

mod page;
pub mod scene;

use std::fs::File;
use std::io::BufWriter;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use clap::Args;
use flowopt_client::{Endpoint, TeamChannel};
use flowopt_planner::problem::Team;
use foxglove::messages::SceneUpdate;
use foxglove::{Channel, McapWriterHandle, RawChannel, Schema, WebSocketServerHandle};
use serde::Serialize;
use tracing::{info, warn};

use flowopt_client::records::{AnswerRecord, SnapshotRecord};

/// How long the watcher waits for an answer before it looks for a snapshot.
const POLL: Duration = Duration::from_millis(2);
/// The Foxglove scene is drawn at most this often (the JSON channels carry
/// every snapshot and answer).
const SCENE_EVERY: Duration = Duration::from_millis(100);

/// The JSON schemas of the two record channels (docs/RECORDING.md).
const SNAPSHOT_SCHEMA: &str = include_str!("snapshot.schema.json");
const ANSWER_SCHEMA: &str = include_str!("answer.schema.json");

/// Where a run's traffic goes besides the robots.
#[derive(Debug, Clone, Default, Args)]
pub struct ObserveArgs {
    /// Record every snapshot, answer and plan to this MCAP file (a new
    /// file: an existing one is an error).
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// Serve the live view: a page at http://ADDR/ (e.g. 0.0.0.0:8080 for
    /// the lab's network) and a Foxglove WebSocket on the next port.
    #[arg(long, value_name = "ADDR")]
    pub live: Option<SocketAddr>,
}

impl ObserveArgs {
    /// The same options for a child process.
    pub fn child_args(&self) -> Vec<String> {
        let mut args = Vec::new();
        if let Some(path) = &self.record {
            args.extend(["--record".to_string(), path.display().to_string()]);
        }
        if let Some(addr) = self.live {
            args.extend(["--live".to_string(), addr.to_string()]);
        }
        args
    }
}

/// A team to watch, as the page draws it.
#[derive(Debug, Clone, Serialize)]
pub struct Watched {
    /// Its name.
    pub name: String,
    /// Robot radius (m).
    pub radius: f64,
    /// The workspace box's corners (m).
    pub min: [f64; 3],
    /// The other corner.
    pub max: [f64; 3],
}

impl Watched {
    /// Team `name` of shape `team`.
    pub fn new(name: &str, team: &Team) -> Self {
        let w = &team.workspace;
        Self {
            name: name.to_string(),
            radius: team.robot.radius,
            min: [w.min.x, w.min.y, w.min.z],
            max: [w.max.x, w.max.y, w.max.z],
        }
    }
}

/// The running watchers and their sinks; [`Observer::finish`] closes the
/// recording.
pub struct Observer {
    stop: Arc<AtomicBool>,
    watchers: Vec<JoinHandle<Result<()>>>,
    recording: Option<(PathBuf, McapWriterHandle<BufWriter<File>>)>,
    live: Option<WebSocketServerHandle>,
}

impl Observer {
    /// Starts watching `teams` under the iceoryx2 `prefix` into the sinks
    /// `args` names; `None` when it names none.
    pub fn start(args: &ObserveArgs, prefix: &str, teams: &[Watched]) -> Result<Option<Self>> {
        if args.record.is_none() && args.live.is_none() {
            return Ok(None);
        }
        let context = foxglove::Context::new();
        let recording = match &args.record {
            Some(path) => {
                let handle = context.mcap_writer().create_new_buffered_file(path).map_err(|e| {
                    anyhow!("cannot record to {}: {e} (a recording is never overwritten)", path.display())
                })?;
                info!("recording to {}", path.display());
                Some((path.clone(), handle))
            }
            None => None,
        };
        let live = match args.live {
            Some(addr) => Some(serve_live(addr, &context, teams)?),
            None => None,
        };
        let stop = Arc::new(AtomicBool::new(false));
        let mut watchers = Vec::new();
        for team in teams {
            let (context, stop, prefix, name) = (context.clone(), stop.clone(), prefix.to_string(), team.clone());
            let watcher = std::thread::Builder::new()
                .name(format!("observe-{}", team.name))
                .spawn(move || watch(&context, &prefix, &name, &stop))
                .context("cannot start a watcher thread")?;
            watchers.push(watcher);
        }
        Ok(Some(Self { stop, watchers, recording, live }))
    }

    /// Stops the watchers, closes the recording and the live view.
    pub fn finish(self) -> Result<()> {
        self.stop.store(true, Ordering::Relaxed);
        for watcher in self.watchers {
            watcher.join().map_err(|_| anyhow!("a watcher thread panicked"))??;
        }
        if let Some((path, handle)) = self.recording {
            handle.close().map_err(|e| anyhow!("cannot finish the recording {}: {e}", path.display()))?;
        }
        if let Some(server) = self.live {
            server.stop().wait_blocking();
        }
        Ok(())
    }
}

/// A JSON channel with its schema.
fn json_channel(
    context: &Arc<foxglove::Context>,
    topic: String,
    name: &str,
    schema: &'static str,
) -> Result<Arc<RawChannel>> {
    context
        .channel_builder(topic)
        .message_encoding("json")
        .schema(Schema::new(name, "jsonschema", schema.as_bytes()))
        .build_raw()
        .map_err(|e| anyhow!("cannot open a recording channel: {e}"))
}

/// One team's watcher: logs every snapshot and answer it sees until `stop`.
fn watch(context: &Arc<foxglove::Context>, prefix: &str, team: &Watched, stop: &AtomicBool) -> Result<()> {
    let channel = TeamChannel::new(prefix, &team.name)?;
    let endpoint = Endpoint::new("flowopt-observe")?;
    let states = endpoint.state_subscriber(&channel)?;
    let mut plans = endpoint.plan_watcher(&channel)?;
    let base = format!("/flowopt/{}", team.name);
    let snapshots = json_channel(context, format!("{base}/snapshot"), "flowopt.Snapshot", SNAPSHOT_SCHEMA)?;
    let answers = json_channel(context, format!("{base}/answer"), "flowopt.Answer", ANSWER_SCHEMA)?;
    let scene: Channel<SceneUpdate> = context.channel_builder(format!("{base}/scene")).build();
    let mut last_plan = None;
    let (mut plan_drawn, mut robots_drawn) = (Instant::now() - SCENE_EVERY, Instant::now() - SCENE_EVERY);
    while !stop.load(Ordering::Relaxed) {
        if let Some(msg) = plans.wait(POLL)? {
            let key = (msg.plan_sequence, msg.plan_origin_ns);
            let record = AnswerRecord::of(&msg, last_plan != Some(key));
            if record.plan.is_some() {
                last_plan = Some(key);
            }
            if plan_drawn.elapsed() >= SCENE_EVERY {
                plan_drawn = Instant::now();
                // The plan followed now, carried by this answer or an earlier one.
                let followed = msg.plan().ok().filter(|_| record.followable);
                scene.log(&scene::plan(&record, followed.as_ref()));
            }
            log_json(&answers, &record);
        }
        if let Some(s) = states.latest()? {
            let record = SnapshotRecord::of(&s);
            if robots_drawn.elapsed() >= SCENE_EVERY {
                robots_drawn = Instant::now();
                scene.log(&scene::snapshot(&record, team.radius));
            }
            log_json(&snapshots, &record);
        }
    }
    Ok(())
}

fn log_json(channel: &RawChannel, record: &impl Serialize) {
    match serde_json::to_vec(record) {
        Ok(bytes) => channel.log(&bytes),
        Err(e) => warn!("cannot encode a record: {e}"),
    }
}

/// Starts the live view's WebSocket (on `addr`'s port + 1, or a free one
/// when `addr`'s port is 0) and its page on `addr`.
fn serve_live(addr: SocketAddr, context: &Arc<foxglove::Context>, teams: &[Watched]) -> Result<WebSocketServerHandle> {
    let ws_port = match addr.port() {
        0 => 0,
        port if port < u16::MAX => port + 1,
        _ => bail!("--live {addr}: the WebSocket needs the next port free"),
    };
    let server = foxglove::WebSocketServer::new()
        .context(context)
        .name("flowopt")
        .bind(addr.ip().to_string(), ws_port)
        .start_blocking()
        .map_err(|e| anyhow!("cannot serve the live view's WebSocket on {}:{ws_port}: {e}", addr.ip()))?;
    let page = page::html(server.port(), teams)?;
    let bound = flowopt_daemon::http::serve(addr, "live-view", "not found: the live view is at /\n", move |path| {
        (path == "/" || path == "/index.html").then(|| ("text/html; charset=utf-8", page.clone()))
    })
    .with_context(|| format!("cannot serve the live view on {addr}"))?;
    info!("live view on http://{bound}/ (Foxglove WebSocket on port {})", server.port());
    Ok(server)
}
