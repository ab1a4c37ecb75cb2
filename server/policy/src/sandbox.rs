//! Untrusted policies in a worker process with memory and time limits.
//!
//! tract constant-folds a model when it loads it and allocates what the shapes say, so a
//! few-hundred-byte model can ask for terabytes. A [`SandboxedPolicy`] loads and runs the
//! model in a child process (the server binary re-executed with a hidden subcommand that calls
//! [`run_worker`]) whose address space, CPU time, file sizes and open files are capped with
//! `setrlimit`, and whose every call has a wall-clock deadline (a watchdog kills it). A model
//! that goes over a limit costs only its own worker; the caller gets
//! [`PolicyError::ResourceLimit`], a client error.
//!
//! The wire between the two is the worker's stdin and stdout: a header (limits, spec, model
//! bytes), a load reply, then one request (batch, histories) and one reply (actions) per call,
//! all little-endian.

use std::io::{BufReader, BufWriter, Read, Write};
use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use seccompiler::{
    SeccompAction, SeccompCmpArgLen, SeccompCmpOp, SeccompCondition, SeccompFilter, SeccompRule,
};

use crate::checks::ModelLimits;
use crate::error::PolicyError;
use crate::onnx::OnnxPolicy;
use crate::policy::{Policy, PolicySpec};

/// The hidden subcommand of the server binary that runs [`run_worker`].
pub const WORKER_SUBCOMMAND: &str = "policy-worker";

const MAGIC: &[u8; 4] = b"UGPW";
/// Largest batch one request may carry.
const MAX_WORKER_BATCH: usize = 1 << 16;
/// Bytes of the worker's stderr kept to explain its death.
const STDERR_TAIL: usize = 4096;

/// Reply kinds.
const OK: u8 = 0;
const INVALID: u8 = 1;
const LIMIT: u8 = 2;
const RUN: u8 = 3;

/// Limits of one policy worker.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SandboxLimits {
    /// Address space of the worker (bytes). Default 1 GiB.
    pub memory_bytes: u64,
    /// CPU seconds the worker may use over its life. Default 900.
    pub cpu_seconds: u64,
    /// Wall-clock time to load and check the model. Default 30 s.
    pub load_timeout: Duration,
    /// Wall-clock time of one batched inference. Default 10 s.
    pub act_timeout: Duration,
    /// Bounds on the graph (size, ops, constants).
    pub model: ModelLimits,
}

impl Default for SandboxLimits {
    fn default() -> Self {
        Self {
            memory_bytes: 1 << 30,
            cpu_seconds: 900,
            load_timeout: Duration::from_secs(30),
            act_timeout: Duration::from_secs(10),
            model: ModelLimits::default(),
        }
    }
}

/// Kills the worker when an armed deadline passes.
struct Watchdog {
    state: Arc<(Mutex<WatchState>, Condvar)>,
    thread: Option<JoinHandle<()>>,
}

#[derive(Default)]
struct WatchState {
    deadline: Option<Instant>,
    fired: bool,
    stop: bool,
}

impl Watchdog {
    fn new(pid: u32) -> Self {
        let state = Arc::new((Mutex::new(WatchState::default()), Condvar::new()));
        let shared = state.clone();
        let thread = std::thread::Builder::new()
            .name("policy-watchdog".into())
            .spawn(move || {
                let (lock, cv) = &*shared;
                let Ok(mut s) = lock.lock() else { return };
                loop {
                    if s.stop {
                        return;
                    }
                    s = match s.deadline {
                        None => match cv.wait(s) {
                            Ok(s) => s,
                            Err(_) => return,
                        },
                        Some(d) if Instant::now() >= d => {
                            // The child is not reaped before the watchdog stops, so its pid
                            // cannot have been reused.
                            // SAFETY: kill(2) with a pid we own and a valid signal number.
                            unsafe {
                                libc::kill(pid as libc::pid_t, libc::SIGKILL);
                            }
                            s.fired = true;
                            s.deadline = None;
                            s
                        }
                        Some(d) => match cv.wait_timeout(s, d - Instant::now()) {
                            Ok((s, _)) => s,
                            Err(_) => return,
                        },
                    };
                }
            })
            .ok();
        Self { state, thread }
    }

    fn arm(&self, timeout: Duration) {
        let (lock, cv) = &*self.state;
        if let Ok(mut s) = lock.lock() {
            s.deadline = Some(Instant::now() + timeout);
            cv.notify_all();
        }
    }

    fn disarm(&self) {
        let (lock, cv) = &*self.state;
        if let Ok(mut s) = lock.lock() {
            s.deadline = None;
            cv.notify_all();
        }
    }

    fn fired(&self) -> bool {
        self.state.0.lock().map(|s| s.fired).unwrap_or(false)
    }
}

impl Drop for Watchdog {
    fn drop(&mut self) {
        {
            let (lock, cv) = &*self.state;
            if let Ok(mut s) = lock.lock() {
                s.stop = true;
                cv.notify_all();
            }
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Builds a [`PolicyError`] of one kind from its message.
type ErrorKind = fn(String) -> PolicyError;

/// A running worker.
struct Worker {
    child: Child,
    stdin: BufWriter<ChildStdin>,
    stdout: BufReader<ChildStdout>,
    watchdog: Watchdog,
    stderr: Arc<Mutex<Vec<u8>>>,
    stderr_thread: Option<JoinHandle<()>>,
    /// Set once the worker died; every later call fails with this (the error's kind, its
    /// message).
    dead: Option<(ErrorKind, String)>,
}

impl Drop for Worker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        if let Some(t) = self.stderr_thread.take() {
            let _ = t.join();
        }
    }
}

/// A policy loaded and run in a worker process with memory and time limits.
pub struct SandboxedPolicy {
    spec: PolicySpec,
    limits: SandboxLimits,
    worker: Mutex<Worker>,
}

impl std::fmt::Debug for SandboxedPolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SandboxedPolicy")
            .field("spec", &self.spec)
            .field("limits", &self.limits)
            .finish_non_exhaustive()
    }
}

fn read_u8(r: &mut impl Read) -> std::io::Result<u8> {
    let mut b = [0u8; 1];
    r.read_exact(&mut b)?;
    Ok(b[0])
}

fn read_u32(r: &mut impl Read) -> std::io::Result<u32> {
    let mut b = [0u8; 4];
    r.read_exact(&mut b)?;
    Ok(u32::from_le_bytes(b))
}

fn read_u64(r: &mut impl Read) -> std::io::Result<u64> {
    let mut b = [0u8; 8];
    r.read_exact(&mut b)?;
    Ok(u64::from_le_bytes(b))
}

fn read_f32s(r: &mut impl Read, out: &mut [f32]) -> std::io::Result<()> {
    let mut buf = vec![0u8; out.len() * 4];
    r.read_exact(&mut buf)?;
    for (v, b) in out.iter_mut().zip(buf.chunks_exact(4)) {
        *v = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    }
    Ok(())
}

fn write_f32s(w: &mut impl Write, values: &[f32]) -> std::io::Result<()> {
    let mut buf = Vec::with_capacity(values.len() * 4);
    for v in values {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    w.write_all(&buf)
}

/// Read a reply's status: Ok(()) for OK, the worker's error otherwise.
fn read_status(r: &mut impl Read) -> std::io::Result<Result<(), PolicyError>> {
    let kind = read_u8(r)?;
    if kind == OK {
        return Ok(Ok(()));
    }
    let len = read_u32(r)? as usize;
    let mut message = vec![0u8; len.min(1 << 16)];
    r.read_exact(&mut message)?;
    let message = String::from_utf8_lossy(&message).into_owned();
    Ok(Err(match kind {
        LIMIT => PolicyError::ResourceLimit(message),
        RUN => PolicyError::Run(message),
        _ => PolicyError::Invalid { message },
    }))
}

impl SandboxedPolicy {
    /// Start a worker from `exe` (a binary that runs [`run_worker`] for its
    /// [`WORKER_SUBCOMMAND`]), load `bytes` in it and check it against `spec`.
    pub fn spawn(
        exe: &Path,
        bytes: &[u8],
        spec: PolicySpec,
        limits: SandboxLimits,
    ) -> Result<Self, PolicyError> {
        // A cheap bound from the wire format first, here: a refused model costs no process.
        // Nothing is decoded in this process: protobuf amplifies (two bytes on the wire can be
        // a whole struct in memory), so decoding happens in the worker, under its limits.
        crate::checks::scan_wire(bytes, &limits.model)?;
        let mut child = Command::new(exe)
            .arg(WORKER_SUBCOMMAND)
            .env_clear()
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| PolicyError::Worker(format!("cannot start `{}`: {e}", exe.display())))?;
        let (Some(stdin), Some(stdout), Some(mut stderr)) =
            (child.stdin.take(), child.stdout.take(), child.stderr.take())
        else {
            let _ = child.kill();
            let _ = child.wait();
            return Err(PolicyError::Worker("the worker's pipes are missing".into()));
        };
        let tail = Arc::new(Mutex::new(Vec::new()));
        let stderr_thread = {
            let tail = tail.clone();
            std::thread::Builder::new()
                .name("policy-stderr".into())
                .spawn(move || {
                    let mut buf = [0u8; 1024];
                    while let Ok(n) = stderr.read(&mut buf) {
                        if n == 0 {
                            break;
                        }
                        if let Ok(mut t) = tail.lock() {
                            t.extend_from_slice(&buf[..n]);
                            let excess = t.len().saturating_sub(STDERR_TAIL);
                            t.drain(..excess);
                        }
                    }
                })
                .ok()
        };
        let watchdog = Watchdog::new(child.id());
        let mut worker = Worker {
            child,
            stdin: BufWriter::new(stdin),
            stdout: BufReader::new(stdout),
            watchdog,
            stderr: tail,
            stderr_thread,
            dead: None,
        };
        worker.watchdog.arm(limits.load_timeout);
        let sent = (|| -> std::io::Result<()> {
            let w = &mut worker.stdin;
            w.write_all(MAGIC)?;
            w.write_all(&limits.memory_bytes.to_le_bytes())?;
            w.write_all(&limits.cpu_seconds.to_le_bytes())?;
            for v in [spec.history, spec.obs_dim, spec.num_actions] {
                w.write_all(&(v as u32).to_le_bytes())?;
            }
            w.write_all(&(bytes.len() as u64).to_le_bytes())?;
            w.write_all(bytes)?;
            w.flush()
        })();
        let loaded = sent.and_then(|()| read_status(&mut worker.stdout));
        worker.watchdog.disarm();
        let policy = Self {
            spec,
            limits,
            worker: Mutex::new(worker),
        };
        match loaded {
            Ok(Ok(())) => Ok(policy),
            Ok(Err(e)) => Err(e),
            Err(_) => Err(policy.death("load the model")),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Worker> {
        // A panicking holder leaves at worst a dead worker, which the next call reports.
        self.worker.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Why the worker is gone (it is killed and reaped here), as a client error.
    fn death(&self, doing: &str) -> PolicyError {
        let mut w = self.lock();
        let _ = w.child.kill();
        let status = w.child.wait().ok();
        if let Some(t) = w.stderr_thread.take() {
            let _ = t.join();
        }
        let tail = w
            .stderr
            .lock()
            .map(|t| String::from_utf8_lossy(&t).into_owned())
            .unwrap_or_default();
        let signal = status.and_then(|s| s.signal());
        let memory_mib = self.limits.memory_bytes >> 20;
        let last = |n: usize| -> String {
            let chars: Vec<char> = tail.trim_end().chars().collect();
            chars[chars.len().saturating_sub(n)..].iter().collect()
        };
        let error = if w.watchdog.fired() {
            let limit = if doing == "load the model" {
                self.limits.load_timeout
            } else {
                self.limits.act_timeout
            };
            PolicyError::ResourceLimit(format!(
                "the policy took longer than the {} s a policy may take to {doing}",
                limit.as_secs_f64()
            ))
        } else if signal == Some(libc::SIGXCPU) {
            PolicyError::ResourceLimit(format!(
                "the policy used more than the {} CPU seconds a policy may use",
                self.limits.cpu_seconds
            ))
        } else if tail.contains("allocat") {
            // Rust's "memory allocation of N bytes failed" before it aborts, or tract's
            // "failed to allocate" panic: the address-space cap was reached.
            PolicyError::ResourceLimit(format!(
                "the policy needed more than the {memory_mib} MiB of memory a policy may use to {doing}"
            ))
        } else if tail.contains("overflowed its stack") {
            PolicyError::ResourceLimit(format!(
                "the policy overflowed the worker's stack trying to {doing} (a graph nested too deep)"
            ))
        } else if let Some(sig) = signal {
            let tail = last(300);
            PolicyError::Crashed(format!(
                "the policy's worker crashed with {} trying to {doing}{}{tail}",
                signal_name(sig),
                if tail.is_empty() { "" } else { ": " }
            ))
        } else {
            let status = status.map_or("unknown".to_string(), |s| s.to_string());
            PolicyError::Invalid {
                message: format!(
                    "the policy's worker stopped ({status}) trying to {doing}: {}",
                    last(300)
                ),
            }
        };
        let kind: ErrorKind = match &error {
            PolicyError::ResourceLimit(_) => PolicyError::ResourceLimit,
            PolicyError::Crashed(_) => PolicyError::Crashed,
            _ => |message| PolicyError::Invalid { message },
        };
        w.dead = Some((kind, error.to_string()));
        error
    }

    /// The worker's process id (for monitoring, and for tests that kill it).
    pub fn worker_pid(&self) -> u32 {
        self.lock().child.id()
    }

    /// The worker's limits.
    pub fn limits(&self) -> &SandboxLimits {
        &self.limits
    }
}

impl Policy for SandboxedPolicy {
    fn spec(&self) -> PolicySpec {
        self.spec
    }

    fn act(&self, history: &[f32], batch: usize, actions: &mut [f32]) -> Result<(), PolicyError> {
        let s = self.spec;
        s.check_call(history, batch, actions)?;
        if batch == 0 {
            return Ok(());
        }
        let rows = MAX_WORKER_BATCH;
        let (w, a) = (s.input_width(), s.num_actions);
        for (hist, act) in history.chunks(rows * w).zip(actions.chunks_mut(rows * a)) {
            let n = hist.len() / w;
            let reply = {
                let mut worker = self.lock();
                if let Some((kind, message)) = &worker.dead {
                    return Err(kind(message.clone()));
                }
                worker.watchdog.arm(self.limits.act_timeout);
                let reply = (|| -> std::io::Result<Result<(), PolicyError>> {
                    worker.stdin.write_all(&(n as u32).to_le_bytes())?;
                    write_f32s(&mut worker.stdin, hist)?;
                    worker.stdin.flush()?;
                    let status = read_status(&mut worker.stdout)?;
                    if status.is_ok() {
                        read_f32s(&mut worker.stdout, act)?;
                    }
                    Ok(status)
                })();
                worker.watchdog.disarm();
                reply
            };
            match reply {
                Ok(status) => status?,
                Err(_) => return Err(self.death("run a batch")),
            }
        }
        if let Some(i) = actions.iter().position(|v| !v.is_finite()) {
            return Err(PolicyError::NonFinite {
                env: i / a,
                joint: i % a,
                value: actions[i],
            });
        }
        Ok(())
    }
}

/// A signal's name and what it usually means.
fn signal_name(signal: i32) -> String {
    let name = match signal {
        libc::SIGSEGV => "SIGSEGV (segmentation fault)",
        libc::SIGBUS => "SIGBUS (bus error)",
        libc::SIGILL => "SIGILL (illegal instruction)",
        libc::SIGFPE => "SIGFPE (arithmetic fault)",
        libc::SIGABRT => "SIGABRT (aborted)",
        libc::SIGSYS => "SIGSYS (a system call the sandbox forbids)",
        libc::SIGKILL => "SIGKILL (killed: by the host's out-of-memory killer or an operator)",
        libc::SIGTERM => "SIGTERM (terminated)",
        libc::SIGPIPE => "SIGPIPE (broken pipe)",
        other => return format!("signal {other}"),
    };
    name.to_string()
}

/// Cap one resource of this process.
/// Confine the worker beyond its resource limits, with what Linux allows without privileges: no
/// new privileges (a setuid binary gains nothing), and its own empty network namespace inside a
/// new user namespace where the kernel lets unprivileged processes make one (elsewhere, as in
/// many containers, the worker keeps the host's network; the model cannot open files or sockets
/// through tract either way). The environment is already empty (`env_clear` at spawn).
fn confine() -> std::io::Result<()> {
    // SAFETY: prctl(2) with PR_SET_NO_NEW_PRIVS and constant arguments.
    if unsafe { libc::prctl(libc::PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: unshare(2) with constant flags, in the still single-threaded worker; on failure the
    // process is left as it was.
    let _ = unsafe { libc::unshare(libc::CLONE_NEWUSER | libc::CLONE_NEWNET) };
    Ok(())
}

/// Argument `index` of a system call, compared as a 32-bit value.
fn arg(index: u8, op: SeccompCmpOp, value: u64) -> Result<SeccompCondition, seccompiler::Error> {
    SeccompCondition::new(index, SeccompCmpArgLen::Dword, op, value).map_err(Into::into)
}

/// The system calls a worker makes once its limits are set: read requests from stdin, write
/// replies and crash messages to stdout and stderr, allocate (no executable memory), wait on
/// futexes, take random seeds, handle signals, abort itself and exit. Measured with strace over
/// the load and runs at batch 1 to 5,000; anything else kills the worker with SIGSYS.
fn syscall_filter() -> Result<seccompiler::BpfProgram, seccompiler::Error> {
    let no_exec = || arg(2, SeccompCmpOp::MaskedEq(libc::PROT_EXEC as u64), 0);
    let fd = |n: u64| -> Result<SeccompRule, seccompiler::Error> {
        SeccompRule::new(vec![arg(0, SeccompCmpOp::Eq, n)?]).map_err(Into::into)
    };
    let any = Vec::new;
    // SAFETY: getpid(2) cannot fail.
    let pid = unsafe { libc::getpid() } as u64;
    let rules: Vec<(i64, Vec<SeccompRule>)> = vec![
        (libc::SYS_read, vec![fd(0)?]),
        (libc::SYS_write, vec![fd(1)?, fd(2)?]),
        (libc::SYS_writev, vec![fd(1)?, fd(2)?]),
        (libc::SYS_mmap, vec![SeccompRule::new(vec![no_exec()?])?]),
        (
            libc::SYS_mprotect,
            vec![SeccompRule::new(vec![no_exec()?])?],
        ),
        (libc::SYS_munmap, any()),
        (libc::SYS_mremap, any()),
        (libc::SYS_madvise, any()),
        (libc::SYS_brk, any()),
        (libc::SYS_futex, any()),
        (libc::SYS_getrandom, any()),
        (libc::SYS_clock_gettime, any()),
        (libc::SYS_rt_sigaction, any()),
        (libc::SYS_rt_sigprocmask, any()),
        (libc::SYS_rt_sigreturn, any()),
        (libc::SYS_sigaltstack, any()),
        (libc::SYS_restart_syscall, any()),
        (libc::SYS_getpid, any()),
        (libc::SYS_gettid, any()),
        // abort(): SIGABRT to this process only (not to the server, which has the same uid).
        (
            libc::SYS_tgkill,
            vec![SeccompRule::new(vec![
                arg(0, SeccompCmpOp::Eq, pid)?,
                arg(2, SeccompCmpOp::Eq, libc::SIGABRT as u64)?,
            ])?],
        ),
        (libc::SYS_exit, any()),
        (libc::SYS_exit_group, any()),
    ];
    let arch = std::env::consts::ARCH.try_into()?;
    let program = SeccompFilter::new(
        rules.into_iter().collect(),
        SeccompAction::KillProcess,
        SeccompAction::Allow,
        arch,
    )?
    .try_into()?;
    Ok(program)
}

/// Install [`syscall_filter`] on this (single-threaded) process. Lazy one-time work that would
/// need more (tract reading the CPU's cache sizes from /sys) is done first.
fn install_syscall_filter() -> std::io::Result<()> {
    let _ = tract_onnx::tract_core::tract_linalg::cache::last_level_cache();
    let filter = syscall_filter().map_err(|e| std::io::Error::other(format!("seccomp: {e}")))?;
    seccompiler::apply_filter(&filter)
        .map_err(|e| std::io::Error::other(format!("cannot install the seccomp filter: {e}")))
}

/// The worker's hidden second argument for tests: make a forbidden system call (open a file)
/// before the first batch. The server never passes it.
pub const SECCOMP_SELF_TEST_ARG: &str = "--seccomp-self-test";

fn limit(resource: libc::__rlimit_resource_t, value: u64) -> std::io::Result<()> {
    let r = libc::rlimit {
        rlim_cur: value as libc::rlim_t,
        rlim_max: value as libc::rlim_t,
    };
    // SAFETY: setrlimit(2) with a valid resource and a pointer to a live rlimit.
    if unsafe { libc::setrlimit(resource, &r) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

fn send_error(w: &mut impl Write, kind: u8, message: &str) -> std::io::Result<()> {
    let bytes = message.as_bytes();
    let bytes = &bytes[..bytes.len().min(1 << 16)];
    w.write_all(&[kind])?;
    w.write_all(&(bytes.len() as u32).to_le_bytes())?;
    w.write_all(bytes)?;
    w.flush()
}

fn error_kind(e: &PolicyError) -> u8 {
    match e {
        PolicyError::TooLarge { .. } | PolicyError::ResourceLimit(_) => LIMIT,
        PolicyError::Run(m) | PolicyError::Build { message: m, .. } if m.contains("allocat") => {
            LIMIT
        }
        PolicyError::Run(_) | PolicyError::NonFinite { .. } => RUN,
        _ => INVALID,
    }
}

/// The worker's side: cap this process, read the model from stdin, load it, then answer
/// batches until stdin closes. Call it first thing in the worker subcommand, with nothing else
/// running in the process.
pub fn run_worker() -> std::io::Result<()> {
    confine()?;
    let mut input = BufReader::new(std::io::stdin().lock());
    let mut output = BufWriter::new(std::io::stdout().lock());
    let mut magic = [0u8; 4];
    input.read_exact(&mut magic)?;
    if &magic != MAGIC {
        return Err(std::io::Error::other("not a policy worker request"));
    }
    let memory = read_u64(&mut input)?;
    let cpu = read_u64(&mut input)?;
    limit(libc::RLIMIT_AS, memory)?;
    limit(libc::RLIMIT_CPU, cpu)?;
    limit(libc::RLIMIT_FSIZE, 0)?;
    limit(libc::RLIMIT_CORE, 0)?;
    limit(libc::RLIMIT_NOFILE, 16)?;
    let self_test = std::env::args().nth(2).as_deref() == Some(SECCOMP_SELF_TEST_ARG);
    // Before the model is decoded: the decoder is the part that parses hostile bytes.
    install_syscall_filter()?;
    let spec = PolicySpec {
        history: read_u32(&mut input)? as usize,
        obs_dim: read_u32(&mut input)? as usize,
        num_actions: read_u32(&mut input)? as usize,
    };
    let len = read_u64(&mut input)?;
    let limits = ModelLimits::default();
    if len > limits.max_bytes as u64 {
        return send_error(
            &mut output,
            LIMIT,
            &PolicyError::TooLarge {
                what: "bytes of the model".into(),
                size: len,
                limit: limits.max_bytes as u64,
            }
            .to_string(),
        );
    }
    let mut bytes = vec![0u8; len as usize];
    input.read_exact(&mut bytes)?;
    let policy = match OnnxPolicy::from_untrusted_bytes(&bytes, spec, &limits) {
        Ok(p) => p,
        Err(e) => return send_error(&mut output, error_kind(&e), &e.to_string()),
    };
    drop(bytes);
    output.write_all(&[OK])?;
    output.flush()?;
    let (w, a) = (spec.input_width(), spec.num_actions);
    let mut history = Vec::new();
    let mut actions = Vec::new();
    loop {
        let batch = match read_u32(&mut input) {
            Ok(b) => b as usize,
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            Err(e) => return Err(e),
        };
        if batch > MAX_WORKER_BATCH {
            return send_error(&mut output, INVALID, "batch too large");
        }
        if self_test {
            // SAFETY: open(2) of a constant NUL-terminated path; the filter kills the process.
            let fd = unsafe { libc::open(c"/etc/hostname".as_ptr(), libc::O_RDONLY) };
            return send_error(&mut output, RUN, &format!("open was allowed (fd {fd})"));
        }
        history.resize(batch * w, 0.0);
        actions.resize(batch * a, 0.0);
        read_f32s(&mut input, &mut history)?;
        match policy.act(&history, batch, &mut actions) {
            Ok(()) => {
                output.write_all(&[OK])?;
                write_f32s(&mut output, &actions)?;
                output.flush()?;
            }
            Err(e) => send_error(&mut output, error_kind(&e), &e.to_string())?,
        }
    }
}
