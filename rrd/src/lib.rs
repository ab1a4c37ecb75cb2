//! unigait-rrd: finished rerun recordings (`.rrd` bytes), served from this process for a
//! viewer to join later ([`Served::rrd`]), or sent to a running viewer ([`send_rrd`],
//! [`send_rrd_until`]).
//!
//! This is all a client needs to replay what the server recorded (an Evaluate reply's
//! recording), so it carries no simulator: `unigait-record`, which draws the envs, builds its
//! served live recordings on [`serve_stream`] and [`Served::from_stream`].
#![warn(missing_docs)]

mod error;
mod serve;

pub use error::RrdError;
pub use rerun::MemoryLimit;
pub use serve::{
    DEFAULT_MEMORY_LIMIT_BYTES, DEFAULT_SERVE_PORT, ServeOptions, Served, proxy_url, send_rrd,
    send_rrd_until, serve_stream,
};
