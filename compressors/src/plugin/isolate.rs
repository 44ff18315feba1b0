//! A plugin in a child process (`isolate = true`): a crash, an `exit` or a hang of the library
//! becomes an error naming the library, the call and the cause (`plugin /abs/libx.so crashed
//! in compress: killed by signal 11 (SIGSEGV)`), and biscale lives on to report it.
//!
//! **Which executable is the child.** The host re-executes a known executable with the
//! environment variable [`CHILD_ENV`] set; [`serve_if_child`], called first thing in that
//! executable's `main`, sees it and serves the plugin protocol instead of running the
//! program. The `biscale` binary does this, and it is the default child: the running
//! executable itself (`std::env::current_exe`), so nothing extra is installed or found. A
//! library user whose `main` does not call [`serve_if_child`] names another executable:
//! [`IsolateOptions::host`], or the [`HOST_ENV`] variable; `biscale-plugin-host` (a binary of
//! this crate) is one, and the tests use it. An executable that does not serve the protocol is
//! recognised at once (no greeting) and killed. A child never starts children of its own.
//!
//! **The child** runs the in-process [`PluginCompressor`](super::PluginCompressor) with all
//! its checks. Before loading the library it moves the pipes it speaks on to private
//! descriptors and points its standard output at its standard error and its standard input at
//! `/dev/null`, so whatever a plugin prints lands on biscale's stderr and can never be
//! mistaken for an answer. A thread reads
//! requests and ends the process the moment its stdin closes, even while the plugin is busy or
//! hung: a child whose parent died (killed, crashed) exits instead of lingering.
//!
//! **The parent** ([`IsolatedPlugin`]) treats the child as untrusted, like the library: every
//! answer is decoded by the artifact reader (which never trusts a length), bounded in size per
//! call, and checked again by the same [`Guard`] the in-process path uses (kernels at load,
//! each form before any gather, each `L*`). Each call (load, compress, one gather) must be
//! answered within the timeout, or the child is killed and reaped; so is it on drop. When the
//! child dies its exit status names the cause. A plugin's own errors and panics come back as
//! the same [`PluginError`]s as in process, and the child goes on serving; after a crash,
//! exit, hang or broken answer the child is gone and later calls say so.
//!
//! **Cost.** `T`, each form the child does not already hold, the light and each `L*` cross
//! the pipes (the last form stays resident in the child, so repeated gathers of one form send
//! only the light). The parent's `build_seconds` and CPU gather times include that transfer,
//! and the setting's `Compressor::stats` say so; a GPU gather runs in the parent on the
//! kernels as plain data and crosses no pipe.
//!
//! **Protocol** ([`wire`]). After the child's 8-byte [`wire::GREETING`], both directions carry
//! frames: a little-endian u64 length, then one artifact (`biscale_core::artifact`: checked,
//! self-describing named fields and typed arrays). Requests and their answers:
//!
//! | request (kind) | carries | answer (kind) |
//! |---|---|---|
//! | `plugin-load` | `path`, `params` (JSON) | `plugin-loaded`: `name`, `kernels` (JSON) |
//! | `plugin-compress` | `T` (shape, `row_ptr`, `col_idx`, `values`), `seed` | `form` (the form) |
//! | `form` | a form the child should hold | `plugin-ok` |
//! | `plugin-gather` | `light_basis`, `light` (3N f32) | `plugin-lstar`: `lstar` (3 rows f32) |
//!
//! Any request may instead be answered by `plugin-error` (`variant`, `call`, `message`,
//! `symbol`, `found`): a [`PluginError`] of the child's in-process load, compress or gather.

use super::{resolve_library, Guard, PluginError, MAX_STR_BYTES};
use biscale_core::artifact::{Artifact, Field};
use biscale_core::compress::{ArrayData, CompressContext, CompressedForm, Compressor};
use biscale_core::gather::LocalRadiance;
use biscale_core::sampling::LightVector;
use biscale_core::transfer::{TransferMatrix, TransferView};
use biscale_kernels::{Count, Factor, FormCheck, KernelDesc, PassDesc, ScratchDesc};
use serde_json::{json, Value};
use std::io::{Read, Write};
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Set (to [`wire::PROTOCOL`]) in a child's environment: serve the plugin protocol.
pub const CHILD_ENV: &str = "BISCALE_PLUGIN_CHILD";
/// Names the child executable when [`IsolateOptions::host`] does not.
pub const HOST_ENV: &str = "BISCALE_PLUGIN_HOST";

/// Largest answer to a load (name and kernels: the WGSL is at most 64 MiB).
const LOAD_ANSWER_MAX: u64 = 4 * MAX_STR_BYTES;
/// Any answer may be an error, whose message may be as long as a plugin's (64 MiB).
const ERROR_ANSWER_MAX: u64 = MAX_STR_BYTES + (1 << 20);
/// A form may be this many times the size of the request that carried `T` (or 1 GiB).
const FORM_PER_T_BYTES: u64 = 16;

/// How to run an isolated plugin.
#[derive(Clone, Debug)]
pub struct IsolateOptions {
    /// The child executable; `None`: the [`HOST_ENV`] variable, else this executable (whose
    /// `main` must call [`serve_if_child`] first).
    pub host: Option<PathBuf>,
    /// How long each call (load, compress, one gather) may take before the child is killed.
    pub timeout: Duration,
}

impl Default for IsolateOptions {
    fn default() -> Self {
        Self { host: None, timeout: Duration::from_secs_f64(super::PluginParams::DEFAULT_TIMEOUT_SECONDS) }
    }
}

/// A plugin running in a child process (see the module docs).
pub struct IsolatedPlugin {
    guard: Guard,
    library_hash: u64,
    params: Value,
    host: PathBuf,
    timeout: Duration,
    pid: u32,
    link: Mutex<Link>,
}

impl std::fmt::Debug for IsolatedPlugin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("IsolatedPlugin")
            .field("path", &self.guard.path)
            .field("kind", &self.guard.kind)
            .field("pid", &self.pid)
            .finish_non_exhaustive()
    }
}

/// What the reader thread hands the parent.
enum Answer {
    Frame(Vec<u8>),
    /// The child closed its answers (it exited or died).
    End,
    /// The child ended before its greeting: it is not a plugin host (or could not start).
    Ungreeted,
    /// Not the protocol (a wrong greeting, an oversized frame, a read error).
    Broken(String),
}

/// The parent's end of one child: the process, a writer and a reader thread, and what the
/// child holds. Dropping it kills and reaps the child.
struct Link {
    path: PathBuf,
    host: PathBuf,
    timeout: Duration,
    child: Option<Child>,
    requests: Option<Sender<Vec<u8>>>,
    answers: Receiver<Answer>,
    /// The largest answer the current call accepts (read by the reader thread).
    answer_max: Arc<AtomicU64>,
    /// The form the child holds (what it compressed or was last sent), as the parent checked it.
    resident: Option<CompressedForm>,
    /// Why the child is gone, once it is.
    gone: Option<String>,
}

impl Link {
    fn start(path: &Path, host: PathBuf, timeout: Duration) -> Result<Self, PluginError> {
        let host_err =
            |message: String| PluginError::Host { path: path.to_path_buf(), host: host.clone(), call: "load", message };
        if std::env::var_os(CHILD_ENV).is_some() {
            return Err(host_err("this process is itself a plugin host child; it starts no children".into()));
        }
        let mut child = Command::new(&host)
            .env(CHILD_ENV, wire::PROTOCOL)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| host_err(format!("cannot start it: {e}")))?;
        let pipes = (child.stdin.take(), child.stdout.take());
        let (requests, to_write) = mpsc::channel();
        let (answered, answers) = mpsc::channel();
        let answer_max = Arc::new(AtomicU64::new(LOAD_ANSWER_MAX));
        let max = answer_max.clone();
        // From here on, an early return drops the link, which kills and reaps the child.
        let link = Self {
            path: path.to_path_buf(),
            host: host.clone(),
            timeout,
            child: Some(child),
            requests: Some(requests),
            answers,
            answer_max,
            resident: None,
            gone: None,
        };
        let (Some(stdin), Some(stdout)) = pipes else {
            return Err(host_err("its pipes were not created".into()));
        };
        // Detached: each ends when its pipe does (the child exits or is killed).
        std::thread::Builder::new()
            .name("plugin-host-writer".into())
            .spawn(move || write_requests(stdin, to_write))
            .and_then(|_| {
                std::thread::Builder::new()
                    .name("plugin-host-reader".into())
                    .spawn(move || read_answers(stdout, answered, max))
            })
            .map_err(|e| host_err(format!("cannot start its pipe threads: {e}")))?;
        Ok(link)
    }

    /// Send one request and wait for its answer (of kind `expect`). A `plugin-error` answer
    /// is the child's [`PluginError`] (the child serves on); anything else that is not the
    /// expected answer ends the child.
    fn call(&mut self, call: &'static str, request: Vec<u8>, max: u64, expect: &str) -> Result<Artifact, PluginError> {
        if let Some(message) = &self.gone {
            return Err(PluginError::Gone { path: self.path.clone(), message: message.clone() });
        }
        let answer = self.exchange(call, request, max).and_then(|a| match a.kind.as_str() {
            k if k == expect => Ok(Ok(a)),
            "plugin-error" => wire::decode_error(&a, &self.path, &self.host, call).map(Err),
            k => Err(self.broken(call, format!("answered with a '{k}' where a '{expect}' was expected"))),
        });
        match answer {
            Ok(answer) => answer,
            Err(e) => {
                self.gone = Some(e.to_string());
                self.stop();
                Err(e)
            }
        }
    }

    fn broken(&self, call: &'static str, message: String) -> PluginError {
        PluginError::Host {
            path: self.path.clone(),
            host: self.host.clone(),
            call,
            message: format!("{message}; killed"),
        }
    }

    /// The answer's artifact, or why there is none (every error here ends the child).
    fn exchange(&mut self, call: &'static str, request: Vec<u8>, max: u64) -> Result<Artifact, PluginError> {
        let deadline = Instant::now() + self.timeout;
        self.answer_max.store(max.max(ERROR_ANSWER_MAX), Ordering::SeqCst);
        // A failed send means the writer stopped (the pipe broke): the reader says why.
        let _ = self.requests.as_ref().map(|r| r.send(request));
        match self.answers.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
            Ok(Answer::Frame(bytes)) => Artifact::decode(&bytes, Path::new("answer"))
                .map_err(|e| self.broken(call, format!("sent a frame that is not a valid artifact: {e}"))),
            Ok(Answer::Broken(message)) => Err(self.broken(call, message)),
            Ok(Answer::End) | Err(RecvTimeoutError::Disconnected) => match self.wait_exit(deadline) {
                Ok(status) => Err(exit_error(&self.path, call, status)),
                Err(message) => Err(self.broken(call, message)),
            },
            Ok(Answer::Ungreeted) => {
                let status = self.wait_exit(deadline).map_or_else(|m| m, |s| s.to_string());
                Err(PluginError::Host {
                    path: self.path.clone(),
                    host: self.host.clone(),
                    call,
                    message: format!(
                        "it ended ({status}) before greeting: is it a plugin host? (its main must call \
                         biscale_compressors::plugin::serve_if_child first)"
                    ),
                })
            }
            Err(RecvTimeoutError::Timeout) => {
                Err(PluginError::Timeout { path: self.path.clone(), call, seconds: self.timeout.as_secs_f64() })
            }
        }
    }

    /// The child closed its answers: wait (until the deadline, at least a second) for it to
    /// exit and reap it.
    fn wait_exit(&mut self, deadline: Instant) -> Result<ExitStatus, String> {
        let deadline = deadline.max(Instant::now() + Duration::from_secs(1));
        let Some(child) = self.child.as_mut() else {
            return Err("the child is gone".into());
        };
        loop {
            match child.try_wait() {
                Ok(Some(status)) => {
                    self.child = None;
                    return Ok(status);
                }
                Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(2)),
                Ok(None) => return Err("it closed its answers without exiting".into()),
                Err(e) => return Err(format!("cannot wait for it: {e}")),
            }
        }
    }

    /// Close the child's requests, kill it and reap it (a no-op once done).
    fn stop(&mut self) {
        self.requests = None;
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The error for a child that ended with `status` before answering `call`.
fn exit_error(path: &Path, call: &'static str, status: ExitStatus) -> PluginError {
    let path = path.to_path_buf();
    match (status.signal(), status.code()) {
        (Some(signal), _) => {
            let name = signal_name(signal);
            let core = if status.core_dumped() { ", core dumped" } else { "" };
            PluginError::Crashed { path, call, cause: format!("killed by signal {signal} ({name}){core}") }
        }
        (None, Some(code)) => PluginError::Exited { path, call, code },
        (None, None) => PluginError::Crashed { path, call, cause: format!("ended with {status}") },
    }
}

/// The name of a signal (and, for SIGKILL, who usually sends it).
fn signal_name(signal: i32) -> &'static str {
    const NAMES: &[(i32, &str)] = &[
        (libc::SIGSEGV, "SIGSEGV"),
        (libc::SIGABRT, "SIGABRT"),
        (libc::SIGBUS, "SIGBUS"),
        (libc::SIGILL, "SIGILL"),
        (libc::SIGFPE, "SIGFPE"),
        (libc::SIGTRAP, "SIGTRAP"),
        (libc::SIGSYS, "SIGSYS"),
        (libc::SIGKILL, "SIGKILL, sent from outside: the out-of-memory killer?"),
        (libc::SIGTERM, "SIGTERM"),
        (libc::SIGINT, "SIGINT"),
        (libc::SIGHUP, "SIGHUP"),
        (libc::SIGQUIT, "SIGQUIT"),
        (libc::SIGPIPE, "SIGPIPE"),
        (libc::SIGALRM, "SIGALRM"),
        (libc::SIGUSR1, "SIGUSR1"),
        (libc::SIGUSR2, "SIGUSR2"),
        (libc::SIGXCPU, "SIGXCPU"),
        (libc::SIGXFSZ, "SIGXFSZ"),
    ];
    NAMES.iter().find(|(s, _)| *s == signal).map_or("an unnamed signal", |(_, n)| n)
}

/// The writer thread: each request as one frame, until the channel closes or the pipe breaks
/// (then `stdin` is dropped: the child sees its requests end).
fn write_requests(mut stdin: ChildStdin, requests: Receiver<Vec<u8>>) {
    for body in requests {
        if wire::write_frame_bytes(&mut stdin, &body).is_err() {
            return;
        }
    }
}

/// The reader thread: the greeting, then frames, each at most the current call's limit.
fn read_answers(mut stdout: ChildStdout, answers: Sender<Answer>, max: Arc<AtomicU64>) {
    let mut greeting = [0u8; 8];
    match read_full(&mut stdout, &mut greeting) {
        Ok(true) if &greeting == wire::GREETING => {}
        Ok(true) => {
            let _ = answers.send(Answer::Broken(format!(
                "it does not serve the plugin protocol: it wrote {:?} where the greeting {:?} was expected \
                 (its main must call biscale_compressors::plugin::serve_if_child first)",
                String::from_utf8_lossy(&greeting),
                String::from_utf8_lossy(wire::GREETING)
            )));
            return;
        }
        Ok(false) => {
            let _ = answers.send(Answer::Ungreeted);
            return;
        }
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            let _ = answers.send(Answer::Ungreeted);
            return;
        }
        Err(e) => {
            let _ = answers.send(Answer::Broken(format!("reading its greeting: {e}")));
            return;
        }
    }
    loop {
        let answer = match wire::read_frame(&mut stdout, max.load(Ordering::SeqCst)) {
            Ok(Some(frame)) => Answer::Frame(frame),
            // A frame cut short is the child dying mid-answer: its status says why.
            Ok(None) => Answer::End,
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Answer::End,
            Err(e) => Answer::Broken(e.to_string()),
        };
        let last = !matches!(answer, Answer::Frame(_));
        if answers.send(answer).is_err() || last {
            return;
        }
    }
}

/// Fill `buf`; `Ok(false)` on end of stream before its first byte.
fn read_full(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<bool> {
    let mut at = 0;
    while at < buf.len() {
        match r.read(&mut buf[at..]) {
            Ok(0) if at == 0 => return Ok(false),
            Ok(0) => return Err(std::io::ErrorKind::UnexpectedEof.into()),
            Ok(n) => at += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(true)
}

impl IsolatedPlugin {
    /// Start a child (see [`IsolateOptions`]) and load the plugin at `path` in it with its
    /// experiment parameters; the name and kernels it reports are checked here as in process.
    pub fn spawn(path: &Path, params: Value, opts: &IsolateOptions) -> Result<Self, PluginError> {
        let (path, library_hash) = resolve_library(path)?;
        let host = match (&opts.host, std::env::var_os(HOST_ENV)) {
            (Some(h), _) => h.clone(),
            (None, Some(h)) => PathBuf::from(h),
            (None, None) => std::env::current_exe().map_err(|e| PluginError::Host {
                path: path.clone(),
                host: PathBuf::from("(this executable)"),
                call: "load",
                message: format!("cannot find it: {e}"),
            })?,
        };
        let mut link = Link::start(&path, host, opts.timeout)?;
        let pid = link.child.as_ref().map_or(0, Child::id);
        let loaded =
            link.call("load", wire::load_request(&path, &params).encode(), LOAD_ANSWER_MAX, "plugin-loaded")?;
        let (name, kernels) = wire::decode_loaded(&loaded).map_err(|m| link.broken("load", m))?;
        // The child is healthy but its plugin's answer is refused: the link's drop stops it.
        let guard = Guard::new(path, name, kernels)?;
        let (host, timeout) = (link.host.clone(), link.timeout);
        Ok(Self { guard, library_hash, params, host, timeout, pid, link: Mutex::new(link) })
    }

    /// The library file as loaded: absolute, with symlinks and `..` resolved.
    pub fn path(&self) -> &Path {
        &self.guard.path
    }

    /// The name the plugin reports (its kind is `plugin:<name>`).
    pub fn name(&self) -> &str {
        &self.guard.name
    }

    /// The child's process id (it stays the same: a child that ended is not restarted).
    pub fn child_id(&self) -> u32 {
        self.pid
    }

    /// The child executable.
    pub fn host(&self) -> &Path {
        &self.host
    }

    /// The timeout of each call.
    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    /// The GPU gather program as plain data (what `Compressor::kernels` returns).
    pub fn gpu_kernels(&self) -> &KernelDesc {
        &self.guard.kernels
    }

    /// Everything the host can check on a form of this plugin (as in process).
    pub fn check_form(&self, form: &CompressedForm) -> Result<(), PluginError> {
        self.guard.check_form(form)
    }

    fn lock(&self) -> MutexGuard<'_, Link> {
        // A panic while holding the lock leaves nothing half-done that the next call trusts.
        self.link.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// [`Compressor::compress`] with the typed error. `build_seconds` is the parent's wall
    /// time: the compress plus moving `T` and the form through the pipes.
    pub fn compress_plugin(
        &self,
        t: &TransferMatrix,
        ctx: &CompressContext<'_>,
    ) -> Result<CompressedForm, PluginError> {
        let start = Instant::now();
        let call = "biscale_plugin_compress";
        let request = wire::compress_request(t, ctx.seed)
            .map_err(|message| PluginError::Plugin { path: self.guard.path.clone(), call, message })?
            .encode();
        let max = (request.len() as u64).saturating_mul(FORM_PER_T_BYTES).max(1 << 30);
        let mut link = self.lock();
        link.resident = None;
        let answer = link.call("compress", request, max, CompressedForm::ARTIFACT)?;
        let mut form = CompressedForm::from_artifact(answer).map_err(|e| PluginError::Invalid {
            path: self.guard.path.clone(),
            call,
            message: e.to_string(),
        })?;
        form.build_seconds = start.elapsed().as_secs_f64();
        self.guard.check_compressed(&form, t.shape(), call)?;
        link.resident = Some(form.clone());
        ctx.report(1.0);
        Ok(form)
    }

    /// [`Compressor::gather`] with the typed error (the form is checked first, here).
    pub fn gather_plugin(&self, form: &CompressedForm, light: &LightVector) -> Result<LocalRadiance, PluginError> {
        let call = "biscale_plugin_gather";
        self.guard.check_gather(form, light, call)?;
        let mut link = self.lock();
        if link.resident.as_ref() != Some(form) {
            link.resident = None;
            link.call("gather", form.to_artifact().encode(), 0, "plugin-ok")?;
            link.resident = Some(form.clone());
        }
        let max = 12 * form.rows() as u64 + (1 << 16);
        let answer = link.call("gather", wire::gather_request(light).encode(), max, "plugin-lstar")?;
        drop(link);
        let rows = wire::decode_lstar(&answer, form.rows()).map_err(|message| PluginError::Invalid {
            path: self.guard.path.clone(),
            call,
            message,
        })?;
        self.guard.lstar(form, rows, call)
    }
}

impl Compressor for IsolatedPlugin {
    forward_plugin_calls!();

    fn params(&self) -> Value {
        json!({ "path": self.guard.path.display().to_string(), "params": self.params, "isolate": true })
    }

    /// Says that the setting ran isolated and that its CPU times include the pipes.
    fn stats(&self, _form: &CompressedForm, _t: TransferView<'_>) -> Option<Value> {
        Some(json!({
            "isolated": true,
            "host": self.host.display().to_string(),
            "timeout_seconds": self.timeout.as_secs_f64(),
            "timing": "build_seconds and gather_ms include moving T, the form, the light and L* through \
                       pipes between biscale and the plugin's child process; a GPU gather runs in biscale \
                       and does not",
        }))
    }

    fn code_identity(&self) -> Option<u64> {
        Some(self.library_hash)
    }
}

/// Serve the plugin protocol and exit if this process is an isolated plugin's child (its
/// environment has [`CHILD_ENV`]); return at once otherwise. Call it first thing in `main`.
pub fn serve_if_child() {
    let Some(version) = std::env::var_os(CHILD_ENV) else { return };
    // Not inherited by anything the plugin starts.
    std::env::remove_var(CHILD_ENV);
    let code = match child::serve(&version.to_string_lossy()) {
        Ok(()) => 0,
        Err(message) => {
            eprintln!("biscale plugin host: {message}");
            2
        }
    };
    std::process::exit(code);
}

/// The child's side.
mod child {
    use super::wire;
    use crate::plugin::{PluginCompressor, PluginError};
    use biscale_core::artifact::Artifact;
    use biscale_core::compress::{CompressContext, CompressedForm};
    use std::fs::File;
    use std::io::Write;
    use std::os::fd::{AsRawFd, FromRawFd};
    use std::path::Path;
    use std::sync::mpsc;

    /// Why a request was not served: the plugin's error, or a request this child cannot use.
    enum Failure {
        Plugin(PluginError),
        Request(String),
    }

    impl From<PluginError> for Failure {
        fn from(e: PluginError) -> Self {
            Failure::Plugin(e)
        }
    }

    /// Requests come on a private copy of stdin, answers go to a private copy of stdout; the
    /// standard descriptors become `/dev/null` (in) and stderr (out) for the plugin.
    fn take_protocol_fds() -> Result<(File, File), String> {
        let null = File::open("/dev/null").map_err(|e| format!("opening /dev/null: {e}"))?;
        let os = |what: &str| format!("{what}: {}", std::io::Error::last_os_error());
        // SAFETY: descriptor calls on this process's own standard descriptors, before any
        // other thread runs; each new descriptor is owned by exactly one `File`.
        unsafe {
            let requests = libc::fcntl(0, libc::F_DUPFD_CLOEXEC, 3);
            if requests < 0 {
                return Err(os("duplicating stdin"));
            }
            let requests = File::from_raw_fd(requests);
            let answers = libc::fcntl(1, libc::F_DUPFD_CLOEXEC, 3);
            if answers < 0 {
                return Err(os("duplicating stdout"));
            }
            let answers = File::from_raw_fd(answers);
            if libc::dup2(2, 1) < 0 {
                return Err(os("pointing stdout at stderr"));
            }
            if libc::dup2(null.as_raw_fd(), 0) < 0 {
                return Err(os("pointing stdin at /dev/null"));
            }
            Ok((requests, answers))
        }
    }

    pub(super) fn serve(version: &str) -> Result<(), String> {
        if version != wire::PROTOCOL {
            return Err(format!("asked for protocol {version:?}, this host speaks {:?}", wire::PROTOCOL));
        }
        let (mut requests, mut answers) = take_protocol_fds()?;
        answers.write_all(wire::GREETING).and_then(|()| answers.flush()).map_err(|e| format!("greeting: {e}"))?;
        let (tx, rx) = mpsc::channel();
        std::thread::Builder::new()
            .name("plugin-requests".into())
            .spawn(move || loop {
                // When the parent closes the requests (it is done, or dead), end now, even if
                // the plugin is busy or hung on the main thread.
                let Ok(Some(frame)) = wire::read_frame(&mut requests, u64::MAX) else {
                    // SAFETY: `_exit` ends the process without running anything else.
                    unsafe { libc::_exit(0) }
                };
                if tx.send(frame).is_err() {
                    // SAFETY: as above (the main loop has already ended).
                    unsafe { libc::_exit(0) }
                }
            })
            .map_err(|e| format!("starting the request reader: {e}"))?;
        let mut state = State { plugin: None, resident: None };
        for frame in rx {
            let answer = match Artifact::decode(&frame, Path::new("request")) {
                Ok(request) => {
                    drop(frame);
                    state.handle(request)
                }
                Err(e) => Err(Failure::Request(e.to_string())),
            };
            let answer = answer.unwrap_or_else(|f| match f {
                Failure::Plugin(e) => wire::encode_error(&e),
                Failure::Request(m) => wire::encode_request_error(&m),
            });
            if wire::write_frame_bytes(&mut answers, &answer.encode()).is_err() {
                // The parent stopped reading: nothing to serve.
                return Ok(());
            }
        }
        Ok(())
    }

    struct State {
        plugin: Option<PluginCompressor>,
        resident: Option<CompressedForm>,
    }

    impl State {
        fn plugin(&self) -> Result<&PluginCompressor, Failure> {
            self.plugin.as_ref().ok_or_else(|| Failure::Request("no plugin loaded yet".into()))
        }

        fn handle(&mut self, request: Artifact) -> Result<Artifact, Failure> {
            match request.kind.as_str() {
                "plugin-load" => {
                    if self.plugin.is_some() {
                        return Err(Failure::Request("a plugin is already loaded".into()));
                    }
                    let (path, params) = wire::decode_load(&request).map_err(Failure::Request)?;
                    let plugin = PluginCompressor::load(&path, params)?;
                    let answer = wire::loaded(plugin.name(), plugin.gpu_kernels());
                    self.plugin = Some(plugin);
                    Ok(answer)
                }
                "plugin-compress" => {
                    self.resident = None;
                    let (t, seed) = wire::decode_compress(request).map_err(Failure::Request)?;
                    let form =
                        self.plugin()?.compress_plugin(&t, &CompressContext { seed, progress: None, sweep: None })?;
                    drop(t);
                    let answer = form.to_artifact();
                    self.resident = Some(form);
                    Ok(answer)
                }
                k if k == CompressedForm::ARTIFACT => {
                    self.resident = None;
                    self.resident =
                        Some(CompressedForm::from_artifact(request).map_err(|e| Failure::Request(e.to_string()))?);
                    Ok(Artifact::new("plugin-ok"))
                }
                "plugin-gather" => {
                    let light = wire::decode_gather(&request).map_err(Failure::Request)?;
                    let form = self.resident.as_ref().ok_or_else(|| Failure::Request("no form to gather".into()))?;
                    let lstar = self.plugin()?.gather_plugin(form, &light)?;
                    Ok(wire::lstar(lstar.values()))
                }
                k => Err(Failure::Request(format!("unknown request '{k}'"))),
            }
        }
    }
}

/// The protocol's frames and messages (see the module docs), public so a test or another
/// host can speak it.
pub mod wire {
    use super::*;

    /// The protocol version: the value of [`CHILD_ENV`] in a child's environment.
    pub const PROTOCOL: &str = "1";
    /// The first eight bytes a child writes.
    pub const GREETING: &[u8; 8] = b"BSPHOST1";

    /// Write one frame: the length of `body`, then `body` (an encoded artifact).
    pub fn write_frame_bytes(w: &mut impl Write, body: &[u8]) -> std::io::Result<()> {
        w.write_all(&(body.len() as u64).to_le_bytes())?;
        w.write_all(body)?;
        w.flush()
    }

    /// Read one frame's body, at most `max` bytes (more is an error, read no further);
    /// `Ok(None)` at the end of the stream between frames. The body grows as bytes arrive,
    /// so a lying length allocates nothing.
    pub fn read_frame(r: &mut impl Read, max: u64) -> std::io::Result<Option<Vec<u8>>> {
        let mut len = [0u8; 8];
        if !read_full(r, &mut len)? {
            return Ok(None);
        }
        let len = u64::from_le_bytes(len);
        if len > max {
            return Err(std::io::Error::other(format!(
                "it announced a {len}-byte frame, more than the {max} bytes this call allows"
            )));
        }
        let mut body = Vec::with_capacity(len.min(1 << 24) as usize);
        r.take(len).read_to_end(&mut body)?;
        if body.len() as u64 != len {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        Ok(Some(body))
    }

    /// Load the plugin at `path` (absolute) with `params`.
    pub fn load_request(path: &Path, params: &Value) -> Artifact {
        Artifact::new("plugin-load")
            .with("path", Field::Str(path.display().to_string()))
            .with("params", Field::Str(params.to_string()))
    }

    pub(super) fn decode_load(a: &Artifact) -> Result<(PathBuf, Value), String> {
        let path = PathBuf::from(a.str("path").map_err(|e| e.to_string())?);
        let params = serde_json::from_str(a.str("params").map_err(|e| e.to_string())?)
            .map_err(|e| format!("params are not JSON: {e}"))?;
        Ok((path, params))
    }

    pub(super) fn loaded(name: &str, kernels: &KernelDesc) -> Artifact {
        Artifact::new("plugin-loaded")
            .with("name", Field::Str(name.into()))
            .with("kernels", Field::Str(kernels_to_json(kernels).to_string()))
    }

    pub(super) fn decode_loaded(a: &Artifact) -> Result<(String, KernelDesc), String> {
        let name = a.str("name").map_err(|e| e.to_string())?.to_string();
        let kernels: Value = serde_json::from_str(a.str("kernels").map_err(|e| e.to_string())?)
            .map_err(|e| format!("its kernels are not JSON: {e}"))?;
        let kernels = kernels_from_json(&kernels).map_err(|e| format!("its kernels: {e}"))?;
        Ok((name, kernels))
    }

    /// Compress `T` with `seed`: the shape and the CSR arrays (u32 pointers and columns).
    pub fn compress_request(t: &TransferMatrix, seed: u64) -> Result<Artifact, String> {
        let csr = t.csr();
        if !csr.is_csr() || csr.nnz() > u32::MAX as usize || csr.cols() > u32::MAX as usize {
            return Err(format!("T must be CSR with at most 2^32 - 1 non-zeros (has {})", csr.nnz()));
        }
        Ok(Artifact::new("plugin-compress")
            .with_shape(t.shape())
            .with("seed", Field::U64(seed))
            .with_array("row_ptr", ArrayData::U32(csr.indptr().to_proper().iter().map(|&p| p as u32).collect()))
            .with_array("col_idx", ArrayData::U32(csr.indices().iter().map(|&c| c as u32).collect()))
            .with_array("values", ArrayData::F32(csr.data().to_vec())))
    }

    pub(super) fn decode_compress(mut a: Artifact) -> Result<(TransferMatrix, u64), String> {
        let e = |e: biscale_core::artifact::ArtifactError| e.to_string();
        let shape = a.shape().map_err(e)?;
        let seed = a.u64("seed").map_err(e)?;
        let (row_ptr, col_idx, values) = match (
            a.take_array("row_ptr").map_err(e)?,
            a.take_array("col_idx").map_err(e)?,
            a.take_array("values").map_err(e)?,
        ) {
            (ArrayData::U32(p), ArrayData::U32(c), ArrayData::F32(v)) => (p, c, v),
            _ => return Err("row_ptr, col_idx and values must be u32, u32 and f32".into()),
        };
        let csr = sprs::CsMat::try_new(
            (shape.rows(), shape.cols()),
            row_ptr.into_iter().map(|p| p as usize).collect(),
            col_idx.into_iter().map(|c| c as usize).collect(),
            values,
        )
        .map_err(|e| format!("not a valid CSR matrix of {shape}: {}", e.3))?;
        let t = TransferMatrix::new(shape.local, shape.light, csr).map_err(|e| e.to_string())?;
        Ok((t, seed))
    }

    /// Gather the form the child holds with `light`.
    pub fn gather_request(light: &LightVector) -> Artifact {
        Artifact::new("plugin-gather")
            .with("light_basis", Field::Str(light.basis().tag()))
            .with_array("light", ArrayData::F32(light.power.iter().flatten().copied().collect()))
    }

    pub(super) fn decode_gather(a: &Artifact) -> Result<LightVector, String> {
        let basis = biscale_core::basis::LightBasis::parse(a.str("light_basis").map_err(|e| e.to_string())?)
            .map_err(|e| e.to_string())?;
        let values = match a.arrays.iter().find(|x| x.name == "light").map(|x| &x.data) {
            Some(ArrayData::F32(v)) if v.len() % 3 == 0 => v,
            _ => return Err("no f32 array 'light' of RGB triples".into()),
        };
        LightVector::new(basis, values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()).map_err(|e| e.to_string())
    }

    pub(super) fn lstar(values: &[[f32; 3]]) -> Artifact {
        Artifact::new("plugin-lstar").with_array("lstar", ArrayData::F32(values.iter().flatten().copied().collect()))
    }

    pub(super) fn decode_lstar(a: &Artifact, rows: usize) -> Result<Vec<[f32; 3]>, String> {
        match a.arrays.iter().find(|x| x.name == "lstar").map(|x| &x.data) {
            Some(ArrayData::F32(v)) if v.len() == 3 * rows => {
                Ok(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
            }
            Some(d) => {
                Err(format!("L* has {} {} values, expected {} f32 (3 per row)", d.len(), d.element_type(), 3 * rows))
            }
            None => Err("the answer has no L*".into()),
        }
    }

    fn error_answer(variant: &str, call: &str, message: String, symbol: &str, found: u64) -> Artifact {
        Artifact::new("plugin-error")
            .with("variant", Field::Str(variant.into()))
            .with("call", Field::Str(call.into()))
            .with("message", Field::Str(message))
            .with("symbol", Field::Str(symbol.into()))
            .with("found", Field::U64(found))
    }

    /// A [`PluginError`] of the child's load, compress or gather.
    pub(super) fn encode_error(e: &PluginError) -> Artifact {
        match e {
            PluginError::Load { message, .. } => error_answer("Load", "", message.clone(), "", 0),
            PluginError::MissingSymbol { symbol, message, .. } => {
                error_answer("MissingSymbol", "", message.clone(), symbol, 0)
            }
            PluginError::AbiVersion { found, .. } => error_answer("AbiVersion", "", String::new(), "", *found as u64),
            PluginError::AbiLayout { found, .. } => error_answer("AbiLayout", "", String::new(), "", *found),
            PluginError::Plugin { call, message, .. } => error_answer("Plugin", call, message.clone(), "", 0),
            PluginError::Panic { call, message, .. } => error_answer("Panic", call, message.clone(), "", 0),
            PluginError::Invalid { call, message, .. } => error_answer("Invalid", call, message.clone(), "", 0),
            PluginError::Wgsl { message, .. } => error_answer("Wgsl", "", message.clone(), "", 0),
            e => encode_request_error(&e.to_string()),
        }
    }

    /// A request the child could not use (a bug of the parent's, or a mismatched build).
    pub(super) fn encode_request_error(message: &str) -> Artifact {
        error_answer("Request", "", message.into(), "", 0)
    }

    /// The calls a child's error may name (the error's `call` is a static string).
    const CALLS: &[&str] = &[
        "biscale_plugin_name",
        "biscale_plugin_kernels",
        "biscale_plugin_compress",
        "biscale_plugin_gather",
        "form check",
    ];

    /// The parent's [`PluginError`] for a `plugin-error` answer to `call` (the library path is
    /// the parent's own); `Err` for an answer that is not one (which ends the child).
    pub(super) fn decode_error(
        a: &Artifact,
        path: &Path,
        host: &Path,
        call: &'static str,
    ) -> Result<PluginError, PluginError> {
        let broken = |m: String| PluginError::Host {
            path: path.to_path_buf(),
            host: host.to_path_buf(),
            call,
            message: format!("sent an unreadable error ({m}); killed"),
        };
        let s = |name: &str| a.str(name).map(str::to_string).map_err(|e| broken(e.to_string()));
        let message = s("message")?;
        let in_call = || {
            let c = s("call")?;
            CALLS.iter().find(|k| **k == c).copied().ok_or_else(|| broken(format!("unknown call '{c}'")))
        };
        let path = path.to_path_buf();
        Ok(match s("variant")?.as_str() {
            "Load" => PluginError::Load { path, message },
            "MissingSymbol" => PluginError::MissingSymbol { path, symbol: s("symbol")?, message },
            "AbiVersion" => {
                let found = a.u64("found").map_err(|e| broken(e.to_string()))?;
                let found = u32::try_from(found).map_err(|_| broken(format!("ABI version {found} exceeds u32")))?;
                PluginError::AbiVersion { path, found }
            }
            "AbiLayout" => PluginError::AbiLayout { path, found: a.u64("found").map_err(|e| broken(e.to_string()))? },
            "Plugin" => PluginError::Plugin { path, call: in_call()?, message },
            "Panic" => PluginError::Panic { path, call: in_call()?, message },
            "Invalid" => PluginError::Invalid { path, call: in_call()?, message },
            "Wgsl" => PluginError::Wgsl { path, message },
            "Request" => PluginError::Host {
                path,
                host: host.to_path_buf(),
                call,
                message: format!("refused the request: {message}"),
            },
            v => return Err(broken(format!("unknown variant '{v}'"))),
        })
    }

    fn count_to_json(c: &Count) -> Value {
        Value::Array(
            c.0.iter()
                .map(|f| match f {
                    Factor::Const(v) => json!(["const", v]),
                    Factor::Rows => json!(["rows"]),
                    Factor::Cols => json!(["cols"]),
                    Factor::Vertices => json!(["vertices"]),
                    Factor::LocalDirs => json!(["local_dirs"]),
                    Factor::Meta(k) => json!(["meta", k]),
                    Factor::MetaPlus(k, v) => json!(["meta_plus", k, v]),
                    Factor::Len(a) => json!(["len", a]),
                })
                .collect(),
        )
    }

    /// A kernel description as JSON (the `kernels` of a `plugin-loaded` answer).
    pub fn kernels_to_json(k: &KernelDesc) -> Value {
        let checks: Vec<Value> = k
            .checks
            .iter()
            .map(|c| match c {
                FormCheck::Len { array, count } => json!({ "len": array, "count": count_to_json(count) }),
                FormCheck::Ptr { array, count, total } => {
                    json!({ "ptr": array, "count": count_to_json(count), "total": count_to_json(total) })
                }
                FormCheck::Below { array, bound } => json!({ "below": array, "bound": count_to_json(bound) }),
                FormCheck::Finite { array } => json!({ "finite": array }),
                FormCheck::FiniteHalf { array } => json!({ "finite_half": array }),
                FormCheck::Range { count, min, max } => {
                    json!({ "range": count_to_json(count), "min": min, "max": max })
                }
                FormCheck::Grouped { ids, ptr, group_rows, bases } => {
                    json!({ "grouped": ids, "ptr": ptr, "group_rows": count_to_json(group_rows), "bases": bases })
                }
            })
            .collect();
        json!({
            "wgsl": k.wgsl,
            "passes": k.passes.iter().map(|p| json!({ "entry_point": p.entry_point, "threads": count_to_json(&p.threads) })).collect::<Vec<_>>(),
            "scratch": k.scratch.iter().map(|s| json!({ "name": s.name, "words": count_to_json(&s.words) })).collect::<Vec<_>>(),
            "meta_keys": k.meta_keys,
            "checks": checks,
        })
    }

    fn str_of(v: &Value, key: &str) -> Result<String, String> {
        v.get(key).and_then(Value::as_str).map(str::to_string).ok_or_else(|| format!("'{key}' is not a string"))
    }

    fn u64_of(v: &Value, key: &str) -> Result<u64, String> {
        v.get(key).and_then(Value::as_u64).ok_or_else(|| format!("'{key}' is not an unsigned integer"))
    }

    fn list<'a>(v: &'a Value, key: &str) -> Result<&'a Vec<Value>, String> {
        v.get(key).and_then(Value::as_array).ok_or_else(|| format!("'{key}' is not a list"))
    }

    fn count_from_json(v: &Value, key: &str) -> Result<Count, String> {
        let mut factors = vec![];
        for f in list(v, key)? {
            let parts = f.as_array().ok_or_else(|| format!("'{key}': factor {f} is not a list"))?;
            let name = || parts.get(1).and_then(Value::as_str).map(str::to_string);
            let num = |i: usize| parts.get(i).and_then(Value::as_u64);
            let tag = parts.first().and_then(Value::as_str).unwrap_or("");
            let factor = match (tag, parts.len()) {
                ("const", 2) => num(1).map(Factor::Const),
                ("rows", 1) => Some(Factor::Rows),
                ("cols", 1) => Some(Factor::Cols),
                ("vertices", 1) => Some(Factor::Vertices),
                ("local_dirs", 1) => Some(Factor::LocalDirs),
                ("meta", 2) => name().map(Factor::Meta),
                ("meta_plus", 3) => name().zip(num(2)).map(|(k, v)| Factor::MetaPlus(k, v)),
                ("len", 2) => name().map(Factor::Len),
                _ => None,
            };
            factors.push(factor.ok_or_else(|| format!("'{key}': {f} is not a count factor"))?);
        }
        Ok(Count(factors))
    }

    /// Inverse of [`kernels_to_json`]; the kind is left empty (the guard sets it).
    pub fn kernels_from_json(v: &Value) -> Result<KernelDesc, String> {
        let passes = list(v, "passes")?
            .iter()
            .map(|p| Ok(PassDesc { entry_point: str_of(p, "entry_point")?, threads: count_from_json(p, "threads")? }))
            .collect::<Result<_, String>>()?;
        let scratch = list(v, "scratch")?
            .iter()
            .map(|s| Ok(ScratchDesc { name: str_of(s, "name")?, words: count_from_json(s, "words")? }))
            .collect::<Result<_, String>>()?;
        let meta_keys = list(v, "meta_keys")?
            .iter()
            .map(|k| k.as_str().map(str::to_string).ok_or_else(|| format!("meta key {k} is not a string")))
            .collect::<Result<_, String>>()?;
        let checks = list(v, "checks")?
            .iter()
            .map(|c| {
                let has = |k: &str| c.get(k).is_some();
                Ok(if has("len") {
                    FormCheck::Len { array: str_of(c, "len")?, count: count_from_json(c, "count")? }
                } else if has("ptr") && has("total") {
                    FormCheck::Ptr {
                        array: str_of(c, "ptr")?,
                        count: count_from_json(c, "count")?,
                        total: count_from_json(c, "total")?,
                    }
                } else if has("below") {
                    FormCheck::Below { array: str_of(c, "below")?, bound: count_from_json(c, "bound")? }
                } else if has("finite") {
                    FormCheck::Finite { array: str_of(c, "finite")? }
                } else if has("finite_half") {
                    FormCheck::FiniteHalf { array: str_of(c, "finite_half")? }
                } else if has("range") {
                    FormCheck::Range {
                        count: count_from_json(c, "range")?,
                        min: u64_of(c, "min")?,
                        max: u64_of(c, "max")?,
                    }
                } else if has("grouped") {
                    FormCheck::Grouped {
                        ids: str_of(c, "grouped")?,
                        ptr: str_of(c, "ptr")?,
                        group_rows: count_from_json(c, "group_rows")?,
                        bases: str_of(c, "bases")?,
                    }
                } else {
                    return Err(format!("{c} is not a form check"));
                })
            })
            .collect::<Result<_, String>>()?;
        Ok(KernelDesc { kind: String::new(), wgsl: str_of(v, "wgsl")?, passes, scratch, meta_keys, checks })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_form_check_and_factor_crosses_the_pipe_unchanged() {
        let count = |f: Vec<Factor>| Count(f);
        let k = KernelDesc {
            kind: String::new(),
            wgsl: "fn f() {}\n// \"quoted\" \u{e9}".into(),
            passes: vec![PassDesc { entry_point: "a".into(), threads: count(vec![Factor::Rows, Factor::Const(3)]) }],
            scratch: vec![ScratchDesc { name: "s".into(), words: count(vec![Factor::MetaPlus("m".into(), 1)]) }],
            meta_keys: vec!["m".into(), "n".into()],
            checks: vec![
                FormCheck::Len { array: "x".into(), count: count(vec![Factor::Cols, Factor::Vertices]) },
                FormCheck::Ptr {
                    array: "p".into(),
                    count: count(vec![Factor::LocalDirs]),
                    total: count(vec![Factor::Len("x".into())]),
                },
                FormCheck::Below { array: "x".into(), bound: count(vec![Factor::Meta("m".into())]) },
                FormCheck::Finite { array: "v".into() },
                FormCheck::FiniteHalf { array: "h".into() },
                FormCheck::Range { count: count(vec![]), min: 1, max: u64::MAX },
                FormCheck::Grouped { ids: "i".into(), ptr: "p".into(), group_rows: count(vec![]), bases: "b".into() },
            ],
        };
        let text = wire::kernels_to_json(&k).to_string();
        assert_eq!(wire::kernels_from_json(&serde_json::from_str(&text).unwrap()).unwrap(), k);
        for (bad, needle) in [
            (json!({}), "'passes' is not a list"),
            (
                json!({ "wgsl": "", "passes": [{ "entry_point": "a", "threads": [["cols", 3]] }], "scratch": [], "meta_keys": [], "checks": [] }),
                "is not a count factor",
            ),
            (
                json!({ "wgsl": "", "passes": [], "scratch": [], "meta_keys": [], "checks": [{ "nope": "x" }] }),
                "is not a form check",
            ),
        ] {
            let e = wire::kernels_from_json(&bad).unwrap_err();
            assert!(e.contains(needle), "{bad}: {e}");
        }
    }

    #[test]
    fn frames_are_bounded_and_errors_round_trip() {
        let mut bytes = vec![];
        wire::write_frame_bytes(&mut bytes, b"hello").unwrap();
        wire::write_frame_bytes(&mut bytes, &[7; 100]).unwrap();
        let mut r = &bytes[..];
        assert_eq!(wire::read_frame(&mut r, 5).unwrap().unwrap(), b"hello");
        let e = wire::read_frame(&mut r, 99).unwrap_err();
        assert!(e.to_string().contains("100-byte frame, more than the 99"), "{e}");
        assert!(wire::read_frame(&mut &[][..], 10).unwrap().is_none());
        // A length that promises more than arrives: nothing is allocated up front.
        let mut short = u64::MAX.to_le_bytes().to_vec();
        short.extend_from_slice(b"abc");
        assert_eq!(wire::read_frame(&mut &short[..], u64::MAX).unwrap_err().kind(), std::io::ErrorKind::UnexpectedEof);

        let (path, host) = (Path::new("/p/libx.so"), Path::new("/h/host"));
        for e in [
            PluginError::Plugin { path: path.into(), call: "biscale_plugin_gather", message: "m".into() },
            PluginError::Panic { path: path.into(), call: "biscale_plugin_compress", message: "m".into() },
            PluginError::Invalid { path: path.into(), call: "form check", message: "m".into() },
            PluginError::AbiVersion { path: path.into(), found: 3 << 16 },
            PluginError::AbiLayout { path: path.into(), found: 42 },
            PluginError::MissingSymbol { path: path.into(), symbol: "s".into(), message: "m".into() },
            PluginError::Load { path: path.into(), message: "m".into() },
            PluginError::Wgsl { path: path.into(), message: "m".into() },
        ] {
            let back = wire::decode_error(&wire::encode_error(&e), path, host, "gather").unwrap();
            assert_eq!(format!("{back:?}"), format!("{e:?}"));
        }
        // A child's error that names a call no plugin makes is a broken answer.
        let forged = wire::encode_error(&PluginError::Plugin { path: path.into(), call: "x", message: "m".into() })
            .with("call", Field::Str("rm -rf".into()));
        let e = wire::decode_error(&forged, path, host, "gather").unwrap_err();
        assert!(e.to_string().contains("unknown call 'rm -rf'"), "{e}");
        let e = wire::decode_error(&wire::encode_request_error("no form"), path, host, "gather").unwrap();
        assert!(e.to_string().contains("refused the request: no form") && e.to_string().contains("/h/host"), "{e}");
    }

    #[test]
    fn signals_and_exit_codes_name_their_cause() {
        let p = Path::new("/p/libx.so");
        let e = exit_error(p, "compress", ExitStatus::from_raw(libc::SIGSEGV));
        assert_eq!(e.to_string(), "plugin /p/libx.so crashed in compress: killed by signal 11 (SIGSEGV)");
        let e = exit_error(p, "gather", ExitStatus::from_raw(3 << 8));
        assert_eq!(e.to_string(), "plugin /p/libx.so exited with status 3 during gather without answering");
        let e = PluginError::Timeout { path: p.into(), call: "compress", seconds: 5.0 };
        assert_eq!(e.to_string(), "plugin /p/libx.so did not answer compress within 5 s; killed");
    }
}
