//! A local `unigait-server` child process, for runs given no `--server` (as the Python CLI's
//! `LocalServer`): `serve --addr 127.0.0.1:0`, its address read from its first line.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use crate::{Error, Result};

/// The server binary: `explicit` if given, else `$UNIGAIT_SERVER_BIN`, else `unigait-server`
/// beside this executable (a cargo target directory), else `unigait-server` on `PATH`.
pub fn server_binary(explicit: Option<&Path>) -> PathBuf {
    if let Some(p) = explicit {
        return p.to_path_buf();
    }
    if let Some(p) = std::env::var_os("UNIGAIT_SERVER_BIN") {
        return PathBuf::from(p);
    }
    let beside = std::env::current_exe().ok().and_then(|exe| {
        // A test binary lives in target/<profile>/deps, the learner in target/<profile>.
        exe.ancestors()
            .skip(1)
            .take(2)
            .map(|d| d.join("unigait-server"))
            .find(|p| p.is_file())
    });
    beside.unwrap_or_else(|| PathBuf::from("unigait-server"))
}

/// A running local server, terminated when dropped.
#[derive(Debug)]
pub struct LocalServer {
    child: Child,
    /// `127.0.0.1:PORT`.
    pub address: String,
}

impl LocalServer {
    /// Start `binary serve --addr 127.0.0.1:0 <extra>` and wait for its address.
    pub fn start(binary: &Path, extra: &[String]) -> Result<Self> {
        let mut child = Command::new(binary)
            .args(["serve", "--addr", "127.0.0.1:0"])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| Error::Run(format!("cannot start {}: {e}", binary.display())))?;
        let stdout = child
            .stdout
            .take()
            .ok_or_else(|| Error::Run("the server's stdout".into()))?;
        let mut reader = BufReader::new(stdout);
        let mut line = String::new();
        reader.read_line(&mut line)?;
        let Some(address) = line.trim().strip_prefix("listening on ").map(String::from) else {
            let _ = child.kill();
            let _ = child.wait();
            return Err(Error::Run(format!(
                "{} did not report its address (first line {line:?})",
                binary.display()
            )));
        };
        // Keep reading its stdout so that the server never blocks on a full pipe.
        std::thread::spawn(move || {
            let mut sink = String::new();
            while reader.read_line(&mut sink).is_ok_and(|n| n > 0) {
                sink.clear();
            }
        });
        Ok(Self { child, address })
    }
}

impl Drop for LocalServer {
    fn drop(&mut self) {
        // SIGTERM first (the server drains its sessions), then make sure.
        let pid = self.child.id().to_string();
        let terminated = Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .is_ok_and(|s| s.success());
        if terminated {
            for _ in 0..100 {
                if matches!(self.child.try_wait(), Ok(Some(_))) {
                    return;
                }
                std::thread::sleep(std::time::Duration::from_millis(50));
            }
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
