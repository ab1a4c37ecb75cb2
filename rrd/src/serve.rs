//! Serving a recording from this process for a viewer to join later.
//!
//! The process hosts rerun's gRPC proxy server (`rerun::grpc_server::GrpcServerSink`): what is
//! logged is buffered there, and a viewer started later with
//! `rerun --connect rerun+http://127.0.0.1:9876/proxy` gets it all, oldest first. The server
//! lives as long as the [`Served`] handle (or the served `unigait_record::Recorder`); the caller
//! decides how long that is (the `unigait-client` CLI: until Ctrl-C or `--serve-for`).

use std::io::BufReader;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr, TcpListener, TcpStream};
use std::time::{Duration, Instant};

use rerun::TimelineName;
use rerun::external::arrow::array::BooleanArray;
use rerun::external::re_uri::ProxyUri;
use rerun::grpc_server::GrpcServerSink;
use rerun::log::{Chunk, LogMsg};
use rerun::sink::{GrpcSink, LogSink as _};
use rerun::{MemoryLimit, PlaybackBehavior, RecordingStream, ServerOptions};

use crate::error::RrdError;

/// rerun's proxy port: a bare `rerun --connect` joins it.
pub const DEFAULT_SERVE_PORT: u16 = 9876;

/// Default cap on what the server buffers for viewers that join later: 1 GiB, rerun's own
/// server default. A rollout recording is far smaller (a few kB per policy step); past the cap
/// rerun drops the oldest non-static data, so a late viewer would miss the start.
pub const DEFAULT_MEMORY_LIMIT_BYTES: u64 = 1 << 30;

/// How long [`Served`] waits for rerun's server thread to accept connections: it binds on its
/// own thread and only logs a failure, so without this check a dead server would go unnoticed.
const LISTEN_TIMEOUT: Duration = Duration::from_secs(10);

/// Where a recording is served and how much of it is kept.
#[derive(Clone, Debug, PartialEq)]
pub struct ServeOptions {
    /// Address the gRPC server listens on. Default `127.0.0.1:9876`: loopback only, since the
    /// proxy has no authentication. Port 0 takes a free port (see [`Served::addr`]).
    pub addr: SocketAddr,
    /// Cap on the buffered data (default [`DEFAULT_MEMORY_LIMIT_BYTES`]).
    pub memory_limit: MemoryLimit,
}

impl Default for ServeOptions {
    fn default() -> Self {
        Self {
            addr: SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), DEFAULT_SERVE_PORT),
            memory_limit: MemoryLimit::from_bytes(DEFAULT_MEMORY_LIMIT_BYTES),
        }
    }
}

impl ServeOptions {
    /// Check the address can be listened on now (e.g. before a long rollout, so that a port
    /// in use fails early). Serving checks again.
    pub fn check(&self) -> Result<(), RrdError> {
        claim_addr(self.addr).map(|_| ())
    }

    fn server_options(&self) -> ServerOptions {
        ServerOptions {
            // A viewer joining after the rollout wants it from the start.
            playback_behavior: PlaybackBehavior::OldestFirst,
            memory_limit: self.memory_limit,
            ..ServerOptions::default()
        }
    }
}

/// The URL a viewer connects to for a server listening on `addr`. An unspecified address
/// (`0.0.0.0`, `::`) is joined locally through loopback.
pub fn proxy_url(addr: SocketAddr) -> String {
    format!("rerun+http://{}/proxy", local_target(addr))
}

/// Where a local client reaches a server listening on `addr`: an unspecified address (`0.0.0.0`,
/// `::`) through loopback, any other as it is.
fn local_target(addr: SocketAddr) -> SocketAddr {
    let ip = match addr.ip() {
        IpAddr::V4(ip) if ip.is_unspecified() => IpAddr::V4(Ipv4Addr::LOCALHOST),
        IpAddr::V6(ip) if ip.is_unspecified() => IpAddr::V6(Ipv6Addr::LOCALHOST),
        ip => ip,
    };
    SocketAddr::new(ip, addr.port())
}

fn serve_err(addr: SocketAddr, reason: impl std::fmt::Display) -> RrdError {
    RrdError::Serve {
        addr: addr.to_string(),
        reason: reason.to_string(),
    }
}

/// Check `addr` can be bound and resolve port 0 to a free port. rerun binds on its server
/// thread and only logs a failure, so a port in use (e.g. by a viewer started with `rerun`,
/// which listens on 9876) is caught here instead. The probe is released before rerun binds:
/// a process taking the port in that instant and listening there itself would go unnoticed.
fn claim_addr(addr: SocketAddr) -> Result<SocketAddr, RrdError> {
    let probe = TcpListener::bind(addr).map_err(|e| {
        let hint = match e.kind() {
            std::io::ErrorKind::AddrInUse if addr.port() == DEFAULT_SERVE_PORT => {
                " (a viewer started with `rerun` listens there: send to it with --connect, or \
                 serve on another port)"
            }
            std::io::ErrorKind::AddrInUse => " (serve on another port, or port 0 for a free one)",
            _ => "",
        };
        serve_err(addr, format!("{e}{hint}"))
    })?;
    probe.local_addr().map_err(|e| serve_err(addr, e))
}

/// Block until the server at `addr` accepts TCP connections.
fn wait_listening(addr: SocketAddr) -> Result<(), RrdError> {
    let target = local_target(addr);
    let start = Instant::now();
    loop {
        match TcpStream::connect_timeout(&target, Duration::from_millis(200)) {
            Ok(_) => return Ok(()),
            Err(e) if start.elapsed() >= LISTEN_TIMEOUT => {
                return Err(serve_err(
                    addr,
                    format!("rerun's server did not start listening: {e}"),
                ));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

/// Build a stream whose sink is rerun's server on a claimed address, and wait until it listens
/// (a live recording served as it is made: `unigait_record::Recorder::serve`).
pub fn serve_stream(
    builder: rerun::RecordingStreamBuilder,
    options: &ServeOptions,
) -> Result<(RecordingStream, SocketAddr), RrdError> {
    let addr = claim_addr(options.addr)?;
    let rec = builder
        .serve_grpc_opts(addr.ip().to_string(), addr.port(), options.server_options())
        .map_err(|e| serve_err(addr, e))?;
    wait_listening(addr)?;
    Ok((rec, addr))
}

/// What keeps the server alive.
enum Keep {
    /// A served live recording's stream: dropping or disconnecting it stops the server.
    Stream(RecordingStream),
    /// A replayed `.rrd`: the sink owns the server.
    Sink(GrpcServerSink),
}

/// A recording being served: the gRPC server runs until [`Served::shutdown`] or drop.
pub struct Served {
    keep: Keep,
    addr: SocketAddr,
}

impl std::fmt::Debug for Served {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Served")
            .field("addr", &self.addr)
            .finish_non_exhaustive()
    }
}

fn decode_rrd(rrd: &[u8]) -> impl Iterator<Item = Result<LogMsg, RrdError>> + '_ {
    re_log_encoding::DecoderApp::decode_lazy(BufReader::new(rrd))
        .map(|m| m.map_err(|e| RrdError::InvalidRrd(e.to_string())))
}

impl Served {
    /// Keep serving a live recording's stream, made with [`serve_stream`] on `addr`.
    pub fn from_stream(rec: RecordingStream, addr: SocketAddr) -> Self {
        Self {
            keep: Keep::Stream(rec),
            addr,
        }
    }

    /// Serve a finished recording (the `.rrd` bytes, e.g. of an Evaluate reply): its messages
    /// go to the server as they are (same recording id, no extra recording), and this returns
    /// once they are all buffered there and the server listens.
    pub fn rrd(rrd: &[u8], options: &ServeOptions) -> Result<Self, RrdError> {
        // Decode everything first: a corrupt file must not leave half a recording served.
        let msgs = decode_rrd(rrd).collect::<Result<Vec<_>, _>>()?;
        if msgs.is_empty() {
            return Err(RrdError::InvalidRrd("no messages".into()));
        }
        if options.memory_limit.is_limited() && rrd.len() as u64 > options.memory_limit.as_bytes() {
            tracing::warn!(
                rrd_bytes = rrd.len(),
                limit = %options.memory_limit,
                "the recording is larger than the serve memory limit: a viewer joining late \
                 misses its start"
            );
        }
        let addr = claim_addr(options.addr)?;
        let sink = GrpcServerSink::new(
            &addr.ip().to_string(),
            addr.port(),
            options.server_options(),
        )
        .map_err(|e| serve_err(addr, e))?;
        for msg in msgs {
            sink.send(msg);
        }
        sink.flush_blocking(Duration::MAX)
            .map_err(|e| serve_err(addr, e))?;
        wait_listening(addr)?;
        Ok(Self {
            keep: Keep::Sink(sink),
            addr,
        })
    }

    /// The address the server listens on (port 0 resolved).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// What a viewer joins: `rerun --connect <url>`, e.g. `rerun+http://127.0.0.1:9876/proxy`.
    pub fn url(&self) -> String {
        proxy_url(self.addr)
    }

    /// Flush what is pending and stop the server (connected viewers keep what they received).
    pub fn shutdown(self) -> Result<(), RrdError> {
        match self.keep {
            Keep::Stream(rec) => {
                let flushed = rec.flush_blocking().map_err(|e| serve_err(self.addr, e));
                rec.disconnect();
                flushed
            }
            // The sink flushes and signals the server to stop when dropped.
            Keep::Sink(sink) => {
                let flushed = sink
                    .flush_blocking(Duration::MAX)
                    .map_err(|e| serve_err(self.addr, e));
                drop(sink);
                flushed
            }
        }
    }
}

/// Send a finished recording (the `.rrd` bytes) to a viewer's gRPC proxy, e.g.
/// `rerun+http://127.0.0.1:9876/proxy`; fails if it is not delivered within `timeout`.
pub fn send_rrd(rrd: &[u8], url: &str, timeout: Duration) -> Result<(), RrdError> {
    send_rrd_until(rrd, url, timeout, None)
}

/// [`send_rrd`], cut after policy step `last_step` when given: data logged on the `step`
/// timeline after it is left out, everything else (static data, the viewer layout) is sent.
/// A viewer following the live stream then shows that step (e.g. to photograph it).
pub fn send_rrd_until(
    rrd: &[u8],
    url: &str,
    timeout: Duration,
    last_step: Option<i64>,
) -> Result<(), RrdError> {
    let uri: ProxyUri = url
        .parse()
        .map_err(|e| RrdError::Open(format!("bad viewer URL `{url}`: {e}")))?;
    let mut msgs = decode_rrd(rrd).collect::<Result<Vec<_>, _>>()?;
    if let Some(last) = last_step {
        msgs = cut_after(msgs, "step", last)?;
    }
    let sink = GrpcSink::new(uri);
    for msg in msgs {
        sink.send(msg);
    }
    sink.flush_blocking(timeout)
        .map_err(|e| RrdError::Open(format!("cannot deliver to the viewer at {url}: {e}")))
}

/// The messages with the rows logged after `last` on `timeline` left out (rows without that
/// timeline, and messages other than data, are kept).
fn cut_after(
    msgs: Vec<LogMsg>,
    timeline: &'static str,
    last: i64,
) -> Result<Vec<LogMsg>, RrdError> {
    let name = TimelineName::from_static_str(timeline);
    let mut out = Vec::with_capacity(msgs.len());
    for msg in msgs {
        let LogMsg::ArrowMsg(store, arrow) = &msg else {
            out.push(msg);
            continue;
        };
        let chunk =
            Chunk::from_arrow_msg(arrow).map_err(|e| RrdError::InvalidRrd(e.to_string()))?;
        let Some(column) = chunk.timelines().get(&name) else {
            out.push(msg);
            continue;
        };
        let keep: Vec<bool> = column.times_raw().iter().map(|&t| t <= last).collect();
        if keep.iter().all(|&k| k) {
            out.push(msg);
        } else if let Some(cut) = chunk.filtered(&BooleanArray::from(keep))
            && cut.num_rows() > 0
        {
            let arrow = cut
                .to_arrow_msg()
                .map_err(|e| RrdError::InvalidRrd(e.to_string()))?;
            out.push(LogMsg::ArrowMsg(store.clone(), arrow));
        }
    }
    Ok(out)
}
