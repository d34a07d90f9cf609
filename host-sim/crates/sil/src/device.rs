//! The link to the device under test: the firmware booted in QEMU (MPS2-AN500 Cortex-M7 or
//! MPS3-AN547 Cortex-M55, `-icount shift=0`, UART0 on a Unix socket) or a real board on a serial port, the reader
//! thread that decodes its replies, and the bytes of link messages, valid or not. The SIL's
//! orchestration (`sil.rs`) and the fault generators (`faults.rs`) both talk through it; it
//! knows neither.

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use epssn::fault::{Record, ResetCause};
use epssn::link::{self, Decoder, Header, Message, Payload};

use crate::target::Target;

/// An owned device reply.
#[derive(Debug, Clone)]
// The texts are read through `Debug` in error messages.
#[allow(dead_code)]
pub(crate) enum Reply {
    Depth {
        reference: u32,
        sources: Vec<u32>,
        instructions: u32,
        bits: Vec<u32>,
    },
    Status(link::Status),
    /// The device's hello reply: its counters, why it last reset and its fault record (until
    /// acknowledged).
    Hello(link::Status, Option<ResetCause>, Option<Record>),
    Error {
        code: u16,
        msg: String,
    },
    /// What the upload slot holds (`upload`, the reply to `chunk` and `upload?`).
    Upload(u8, Option<link::Held>),
    /// A reply the host could not decode (the firmware must never send one).
    Garbled(String),
    Other(String),
}

/// The reply decoded from the device's bytes, owned so it can cross to the reader's channel.
fn owned(event: Result<Message<'_>, link::DecodeError>) -> Reply {
    match event {
        Ok(Message::Depth {
            reference,
            sources,
            instructions,
            depth,
            ..
        }) => Reply::Depth {
            reference,
            sources: sources.to_vec(),
            instructions,
            bits: (0..depth.len())
                .filter_map(|i| depth.get(i).map(|d| d.to_bits()))
                .collect(),
        },
        Ok(Message::Status { status, .. }) => Reply::Status(status),
        Ok(Message::Hello {
            status: Some(status),
            reset,
            record,
            ..
        }) => match record.map(Record::from_bytes) {
            Some(None) => Reply::Garbled("hello: invalid fault record".into()),
            r => Reply::Hello(status, reset, r.flatten()),
        },
        Ok(Message::Error { code, msg, .. }) => Reply::Error {
            code,
            msg: msg.to_string(),
        },
        Ok(Message::Upload { slot, held, .. }) => Reply::Upload(slot, held),
        Ok(m) => Reply::Other(m.kind().to_string()),
        Err(e) => Reply::Garbled(e.to_string()),
    }
}

/// QEMU running the firmware (or a board on a serial port), its link and the reply reader.
pub(crate) struct Device {
    qemu: Option<Child>,
    /// QEMU's QMP socket (`system_reset`), when booted with one.
    qmp: Option<UnixStream>,
    link: Box<dyn Write + Send>,
    replies: Receiver<Reply>,
    console: Arc<Mutex<Vec<String>>>,
    dir: PathBuf,
    timeout: Duration,
}

impl Device {
    /// Boots `elf` in QEMU on `target`'s board with UART0 on a Unix socket, and connects to it.
    pub(crate) fn boot(elf: &Path, timeout: Duration, target: Target) -> Result<Self> {
        Self::boot_with(elf, timeout, target, false)
    }

    /// [`Device::boot`], with a QMP socket for [`Device::reset`] when `resettable`.
    pub(crate) fn boot_with(
        elf: &Path,
        timeout: Duration,
        target: Target,
        resettable: bool,
    ) -> Result<Self> {
        let dir = std::env::temp_dir().join(format!("epssn-sil-{}", std::process::id()));
        std::fs::create_dir_all(&dir)?;
        let sock = dir.join("link.sock");
        let _ = std::fs::remove_file(&sock);
        let qmp_sock = dir.join("qmp.sock");
        let mut qemu = target.qemu();
        if resettable {
            let _ = std::fs::remove_file(&qmp_sock);
            qemu.arg("-qmp")
                .arg(format!("unix:{},server=on,wait=off", qmp_sock.display()));
        }
        let mut qemu = qemu
            .args([
                "-semihosting-config",
                "enable=on,target=native,arg=serve",
                "-icount",
                "shift=0",
                "-chardev",
            ])
            .arg(format!(
                "socket,id=link,path={},server=on,wait=on",
                sock.display()
            ))
            .args(["-serial", "chardev:link", "-kernel"])
            .arg(elf)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .context("starting qemu-system-arm (is QEMU installed?)")?;
        let console = Arc::new(Mutex::new(Vec::new()));
        for pipe in [
            qemu.stdout
                .take()
                .map(|p| Box::new(p) as Box<dyn Read + Send>),
            qemu.stderr
                .take()
                .map(|p| Box::new(p) as Box<dyn Read + Send>),
        ]
        .into_iter()
        .flatten()
        {
            let console = console.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(pipe).lines().map_while(|l| l.ok()) {
                    if let Ok(mut c) = console.lock() {
                        c.push(line);
                    }
                }
            });
        }
        let start = Instant::now();
        let link = loop {
            match UnixStream::connect(&sock) {
                Ok(s) => break s,
                Err(e) => {
                    if let Ok(Some(status)) = qemu.try_wait() {
                        bail!("QEMU exited before the link came up ({status})");
                    }
                    if start.elapsed() > Duration::from_secs(20) {
                        let _ = qemu.kill();
                        bail!("QEMU link socket {}: {e}", sock.display());
                    }
                    std::thread::sleep(Duration::from_millis(50));
                }
            }
        };
        let reader = link.try_clone()?;
        let mut device = Self::over(Box::new(link), Box::new(reader), timeout);
        device.qemu = Some(qemu);
        if resettable {
            let mut qmp = UnixStream::connect(&qmp_sock)
                .with_context(|| format!("QMP socket {}", qmp_sock.display()))?;
            qmp.write_all(b"{\"execute\":\"qmp_capabilities\"}\n")?;
            device.qmp = Some(qmp);
        }
        device.console = console;
        device.dir = dir;
        Ok(device)
    }

    /// A board on a serial port: no process, the port is the link.
    pub(crate) fn serial(port: &Path, baud: u32, timeout: Duration) -> Result<Self> {
        let file = crate::serial::open(port, baud)?;
        let reader = file.try_clone()?;
        Ok(Self::over(Box::new(file), Box::new(reader), timeout))
    }

    /// The reply reader on `reader`, messages out on `link`.
    fn over(
        link: Box<dyn Write + Send>,
        mut reader: Box<dyn Read + Send>,
        timeout: Duration,
    ) -> Self {
        let (tx, replies) = channel();
        std::thread::spawn(move || {
            let mut decoder = Box::new(Decoder::new());
            let mut buf = [0u8; 4096];
            while let Ok(n) = reader.read(&mut buf) {
                if n == 0 {
                    break;
                }
                for &b in &buf[..n] {
                    decoder.push(b);
                    while let Some(ev) = decoder.poll() {
                        if tx.send(owned(ev)).is_err() {
                            return;
                        }
                    }
                }
            }
        });
        Self {
            qemu: None,
            qmp: None,
            link,
            replies,
            console: Arc::new(Mutex::new(Vec::new())),
            dir: PathBuf::new(),
            timeout,
        }
    }

    /// Resets the emulated board now, as a power cut would (QMP `system_reset`): whatever the
    /// firmware was doing stops mid-instruction; RAM that nothing loads (the update
    /// partition) keeps its bytes.
    pub(crate) fn reset(&mut self) -> Result<()> {
        let qmp = self
            .qmp
            .as_mut()
            .context("this device cannot be reset (no QMP socket)")?;
        qmp.write_all(b"{\"execute\":\"system_reset\"}\n")
            .context("QMP system_reset")
    }

    /// The console lines so far that contain `word`.
    pub(crate) fn console_lines(&self, word: &str) -> Vec<String> {
        self.console
            .lock()
            .map(|c| c.iter().filter(|l| l.contains(word)).cloned().collect())
            .unwrap_or_default()
    }

    /// Sends raw bytes (a fault may be any bytes at all).
    pub(crate) fn send(&mut self, bytes: &[u8]) -> Result<()> {
        self.link.write_all(bytes).context("writing to the link")
    }

    /// Encodes `msg` and sends it.
    pub(crate) fn send_msg(&mut self, msg: &Message<'_>) -> Result<()> {
        let mut v = Vec::new();
        link::encode(msg, &mut |b: &[u8]| {
            v.extend_from_slice(b);
            Ok::<(), ()>(())
        })
        .map_err(|e| anyhow!("encoding: {e:?}"))?;
        self.send(&v)
    }

    /// The next reply, or an error with the console's text after the timeout.
    pub(crate) fn reply(&mut self) -> Result<Reply> {
        match self.replies.recv_timeout(self.timeout) {
            Ok(r) => Ok(r),
            Err(RecvTimeoutError::Timeout) => bail!(
                "no reply from the firmware within {:?}; console:\n{}",
                self.timeout,
                self.console_text()
            ),
            Err(RecvTimeoutError::Disconnected) => {
                bail!("the link closed; console:\n{}", self.console_text())
            }
        }
    }

    /// The next reply if one comes within `wait`.
    pub(crate) fn reply_within(&mut self, wait: Duration) -> Result<Option<Reply>> {
        match self.replies.recv_timeout(wait) {
            Ok(r) => Ok(Some(r)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => {
                bail!("the link closed; console:\n{}", self.console_text())
            }
        }
    }

    fn console_text(&self) -> String {
        self.console
            .lock()
            .map(|c| c.join("\n"))
            .unwrap_or_default()
    }

    /// Waits for QEMU to exit; true when it exited successfully (a board resets instead: true).
    pub(crate) fn wait_exit(&mut self) -> bool {
        let Some(qemu) = self.qemu.as_mut() else {
            return true;
        };
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(30) {
            if let Ok(Some(status)) = qemu.try_wait() {
                return status.success();
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        false
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        if let Some(qemu) = self.qemu.as_mut() {
            if let Ok(None) = qemu.try_wait() {
                let _ = qemu.kill();
                let _ = qemu.wait();
            }
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// The bytes of a message with header `h` and any `payload`, valid or not for `h`.
pub(crate) fn raw_bytes(h: &Header<'_>, payload: &[u8]) -> Vec<u8> {
    let mut v = Vec::new();
    let _ = link::encode_raw(h, Payload::Bytes(payload), &mut |b: &[u8]| {
        v.extend_from_slice(b);
        Ok::<(), ()>(())
    });
    v
}

/// The bytes of a valid message.
pub(crate) fn msg_bytes(msg: &Message<'_>) -> Vec<u8> {
    let mut v = Vec::new();
    let _ = link::encode(msg, &mut |b: &[u8]| {
        v.extend_from_slice(b);
        Ok::<(), ()>(())
    });
    v
}
