//! The link server the firmware runs: decodes messages from any `embedded_io` byte stream,
//! pairs frames by roll and checks each candidate pair's relative rotation (docs/POSE.md),
//! answers with depth maps, status and errors (docs/LINK.md).
//! Board-independent: the UART comes in as `embedded_io` 0.7 traits, the busy LED as an
//! `embedded_hal` [`OutputPin`], the clock and the stack probe as closures, so host tests drive
//! it with a mock serial line and pin.
//!
//! The serial line is taken as a UART is, not as a file: errors on the read side (overrun,
//! framing, noise, parity) are line errors, not the end of the link. The bytes they cost are
//! lost and the link decoder resynchronises on the next sync pattern, answering the damaged
//! message with an error as it does for corrupt bytes; the server counts them
//! ([`Server::line_errors`]). A read that returns no bytes (`Ok(0)`, which some drivers' blocking
//! reads return on an empty receive ring) is retried, never taken as the end of the stream.
//! Only a write error, or a `shutdown` message, ends [`Server::serve`].

#[cfg(feature = "defmt")]
macro_rules! log {
    ($($t:tt)*) => { defmt::info!($($t)*) };
}
#[cfg(not(feature = "defmt"))]
macro_rules! log {
    ($($t:tt)*) => {{}};
}

use crate::config;
use crate::fault::{Record, ResetCause};
use crate::link::{
    self, encode, error_text, DecodeError, Decoder, DepthData, ErrorCode, Held, Message, Serving,
    Status, MAX_ERROR_TEXT,
};
use crate::model::{Model, Workspace};
use crate::pairing::FeatureCache;
use embedded_hal::digital::OutputPin;
use embedded_io::{Read, ReadReady, Write};
use fixed::types::U16F16;

/// Why a model update step was refused: its link code (13–23) and a short text.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refusal {
    /// The code the error reply carries.
    pub code: ErrorCode,
    /// Why, as the error reply's text.
    pub text: heapless::String<MAX_ERROR_TEXT>,
}

/// A board's model updates (docs/UPDATE.md): the server hands it the `chunk`, `upload?` and
/// `commit` messages and says in each hello which model serves. Without one, those messages
/// are answered `Unexpected`.
pub trait Updates {
    /// The model that serves.
    fn serving(&self) -> Serving;
    /// The slot uploads go to and what it holds.
    fn held(&self) -> (u8, Option<Held>);
    /// Writes a chunk of the upload (offset in the image, CRC-32 of `data`).
    fn chunk(&mut self, offset: u32, data: &[u8], crc: u32) -> Result<(), Refusal>;
    /// Checks the held upload, runs the self-test on it with the server's scratch, and records
    /// it as the model that serves from the next start; returns that model.
    fn commit(
        &mut self,
        workspace: &mut Workspace,
        cache: &mut FeatureCache,
        depth: &mut [U16F16; config::DEPTH_LEN],
    ) -> Result<Serving, Refusal>;
    /// Called once the reply to a successful commit is sent: makes the committed model serve
    /// (the QEMU boards reset and boot it).
    fn switch(&mut self);
}

/// What the server works with, all in static memory.
pub struct Server<'a> {
    /// The verified model.
    pub model: &'a Model<'a>,
    /// Inference scratch.
    pub workspace: &'a mut Workspace,
    /// Cached features for pairing.
    pub cache: &'a mut FeatureCache,
    /// The depth map being sent.
    pub depth: &'a mut [U16F16; config::DEPTH_LEN],
    /// Ticks of a free-running counter.
    pub now: &'a dyn Fn() -> u32,
    /// Instructions per tick of `now` (QEMU: 40 per CMSDK timer tick under `-icount`). A board
    /// with a cycle counter passes 1 and its `now` counts core cycles: the figure it reports
    /// in depth replies is then cycles (boards/stm32h743).
    pub instructions_per_tick: u32,
    /// Ticks of line silence after which a partial message is abandoned.
    pub idle_ticks: u32,
    /// Stack high-water mark, bytes.
    pub stack_high_water: &'a dyn Fn() -> u32,
    /// Counters.
    pub status: Status,
    /// Read-side errors of the serial line since start (each lost one or more bytes). Not on
    /// the wire (the status reply's fields are docs/LINK.md's): boards log it.
    pub line_errors: u32,
    /// Feeds the board's watchdog; called once per pass of the serving loop, so a pass that
    /// never ends (a hang) lets it expire. No-op by default.
    pub feed: &'a dyn Fn(),
    /// Why the device last reset, reported in every hello reply.
    pub reset: ResetCause,
    /// The fault record of the last reset, sent with hello replies until a host's hello
    /// acknowledges it (`ack` = its [`Record::id`]).
    pub fault: Option<Record>,
    /// Forgets the board's stored record, once acknowledged. No-op by default.
    pub clear_fault: &'a dyn Fn(),
    /// Test builds only: provokes the fault an `inject` message names
    /// ([`fault::inject`](crate::fault::inject)); returns for a code it does not know.
    #[cfg(feature = "fault-injection")]
    pub inject: &'a dyn Fn(u16),
    /// The board's model updates, if it takes them.
    pub updates: Option<&'a mut dyn Updates>,
    tx_seq: u32,
}

/// The default of [`Server::feed`] and [`Server::clear_fault`].
fn nothing() {}

impl<'a> Server<'a> {
    /// A server with zeroed counters.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        model: &'a Model<'a>,
        workspace: &'a mut Workspace,
        cache: &'a mut FeatureCache,
        depth: &'a mut [U16F16; config::DEPTH_LEN],
        now: &'a dyn Fn() -> u32,
        instructions_per_tick: u32,
        idle_ticks: u32,
        stack_high_water: &'a dyn Fn() -> u32,
    ) -> Self {
        Self {
            model,
            workspace,
            cache,
            depth,
            now,
            instructions_per_tick,
            idle_ticks,
            stack_high_water,
            status: Status::default(),
            line_errors: 0,
            feed: &nothing,
            reset: ResetCause::PowerOn,
            fault: None,
            clear_fault: &nothing,
            #[cfg(feature = "fault-injection")]
            inject: &|_| {},
            updates: None,
            tx_seq: 0,
        }
    }

    /// A read-side error of the line: counted (and logged); the link goes on.
    fn line_error<E: embedded_io::Error>(&mut self, _error: &E) {
        self.line_errors = self.line_errors.wrapping_add(1);
        #[cfg(feature = "defmt")]
        defmt::warn!("link line error: {}", defmt::Debug2Format(_error));
    }

    fn next_seq(&mut self) -> u32 {
        self.tx_seq = self.tx_seq.wrapping_add(1);
        self.tx_seq
    }

    fn send<W: Write>(&mut self, uart: &mut W, msg: &Message<'_>) -> Result<(), W::Error> {
        match encode(msg, &mut |b: &[u8]| uart.write_all(b)) {
            Ok(_) => Ok(()),
            Err(link::EncodeError::Sink(e)) => Err(e),
            // Our own headers always fit; nothing sensible to send otherwise.
            Err(link::EncodeError::HeaderTooLong) => Ok(()),
        }
    }

    fn send_error<W: Write>(
        &mut self,
        uart: &mut W,
        code: ErrorCode,
        text: &impl core::fmt::Display,
    ) -> Result<(), W::Error> {
        self.status.errors = self.status.errors.wrapping_add(1);
        let msg = error_text(text);
        let seq = self.next_seq();
        self.send(
            uart,
            &Message::Error {
                seq,
                code: code.code(),
                msg: msg.as_str(),
            },
        )
    }

    /// A status reply, or with `hello` the reply to a hello (same counters). Not inlined: one
    /// copy for its four callers keeps the firmware within its flash.
    #[inline(never)]
    fn send_status<W: Write>(&mut self, uart: &mut W, hello: bool) -> Result<(), W::Error> {
        self.status.stack_high_water = (self.stack_high_water)();
        self.status.cached = self.cache.len() as u32;
        let seq = self.next_seq();
        let mut status = self.status;
        // The serving model: in a hello (the reply to a commit sets it itself, `update`).
        if hello {
            status.model = self.updates.as_deref().map(|u| u.serving());
        }
        let record = self.fault.filter(|_| hello).map(|f| f.to_bytes());
        let msg = if hello {
            Message::Hello {
                seq,
                status: Some(status),
                reset: Some(self.reset),
                record: record.as_ref().map(|r| &r[..]),
                ack: None,
            }
        } else {
            Message::Status { seq, status }
        };
        self.send(uart, &msg)
    }

    /// A frame: features into the cache, then a depth map if it completes a view set, else
    /// a status reply.
    fn frame<W: Write, L: OutputPin>(
        &mut self,
        uart: &mut W,
        led: &mut L,
        seq: u32,
        roll_deg: f32,
        attitude: Option<crate::attitude::Attitude>,
        image: &[u8],
    ) -> Result<(), W::Error> {
        let _ = led.set_high();
        let start = (self.now)();
        let model = self.model;
        let ws = &mut *self.workspace;
        let inserted = self
            .cache
            .insert_with_attitude(seq, roll_deg, attitude, |f| model.features(image, ws, f));
        let newest = match inserted {
            Ok(f) => f,
            Err(e) => {
                let _ = led.set_low();
                return self.send_error(uart, ErrorCode::Model, &Debug(e));
            }
        };
        self.status.frames = self.status.frames.wrapping_add(1);
        // No candidate, or one the gate rejected: a status reply that says which and why.
        let set = match self.cache.find_checked(&newest, self.model.views()) {
            Some(Ok(set)) => set,
            found => {
                self.status.pair = found.and_then(|r| r.err());
                #[cfg(feature = "defmt")]
                if let Some(p) = self.status.pair {
                    log!(
                        "pair {} -> {} rejected: {}",
                        p.reference,
                        p.source,
                        p.verdict.reason()
                    );
                }
                let _ = led.set_low();
                return self.send_status(uart, false);
            }
        };
        self.status.pair = Some(set.check);
        // The depth map, in a block so the borrows of the cached features end before replying.
        let computed = {
            let mut sources: heapless::Vec<&[i8], { link::MAX_SOURCES }> = heapless::Vec::new();
            let mut source_seqs: heapless::Vec<u32, { link::MAX_SOURCES }> = heapless::Vec::new();
            for f in set.sources() {
                if let Some(feats) = self.cache.features(f) {
                    let _ = sources.push(&feats[..]);
                    let _ = source_seqs.push(f.seq);
                }
            }
            match set
                .reference()
                .and_then(|r| Some((r.seq, self.cache.features(r)?)))
            {
                Some((reference, ref_feats)) => self
                    .model
                    .depth_from_features(ref_feats, &sources, self.workspace, &mut self.depth[..])
                    .map(|()| (reference, source_seqs)),
                None => Err(crate::model::Error::SourceCount(0)),
            }
        };
        let ticks = (self.now)().wrapping_sub(start);
        let _ = led.set_low();
        let (reference, source_seqs) = match computed {
            Ok(x) => x,
            Err(e) => return self.send_error(uart, ErrorCode::Model, &Debug(e)),
        };
        let instructions = ticks.saturating_mul(self.instructions_per_tick);
        let seq = self.next_seq();
        self.status.depth_maps = self.status.depth_maps.wrapping_add(1);
        log!("depth map {} instructions", instructions);
        let depth = &*self.depth;
        let msg = Message::Depth {
            seq,
            reference,
            sources: source_seqs,
            instructions,
            depth: DepthData::Values(&depth[..]),
            pair: Some(set.check),
        };
        // `self.send` would borrow `self` again; encode directly.
        match encode(&msg, &mut |b: &[u8]| uart.write_all(b)) {
            Err(link::EncodeError::Sink(e)) => Err(e),
            _ => Ok(()),
        }
    }

    /// One decoded event. Returns true on shutdown.
    fn handle<W: Write, L: OutputPin>(
        &mut self,
        uart: &mut W,
        led: &mut L,
        event: Result<Message<'_>, DecodeError>,
    ) -> Result<bool, W::Error> {
        match event {
            Err(e) => {
                log!("link error {}", e.code().code());
                self.send_error(uart, e.code(), &e)?;
            }
            Ok(Message::Frame {
                seq,
                roll_deg,
                attitude,
                image,
            }) => self.frame(uart, led, seq, roll_deg, attitude, image)?,
            Ok(Message::StatusRequest { .. }) => self.send_status(uart, false)?,
            #[cfg(feature = "fault-injection")]
            Ok(Message::Inject { what, .. }) => {
                (self.inject)(what);
                self.send_status(uart, false)?;
            }
            Ok(Message::Hello {
                status: None,
                record: None,
                ack,
                ..
            }) => {
                // A new session: the decoder accepted the hello whatever its seq; the frames
                // of the old session are forgotten and the replies' seqs restart at 1.
                self.acknowledge(ack);
                self.cache.clear();
                self.status.pair = None;
                self.tx_seq = 0;
                self.send_status(uart, true)?;
            }
            Ok(Message::Shutdown { .. }) => {
                self.send_status(uart, false)?;
                uart.flush()?;
                return Ok(true);
            }
            Ok(
                m
                @ (Message::Chunk { .. } | Message::UploadRequest { .. } | Message::Commit { .. }),
            ) if self.updates.is_some() => self.update(uart, m)?,
            Ok(m) => self.send_error(uart, ErrorCode::Unexpected, &m.kind())?,
        }
        Ok(false)
    }

    /// A model update message, for the board's [`Updates`]: a `chunk` or `upload?` is answered
    /// by what the upload slot holds, a `commit` by a status naming the model that serves (then
    /// the switch), each refusal by an error with its code.
    #[inline(never)]
    fn update<W: Write>(&mut self, uart: &mut W, m: Message<'_>) -> Result<(), W::Error> {
        let Some(updates) = self.updates.as_deref_mut() else {
            return Ok(());
        };
        let r = match m {
            Message::Chunk {
                offset, crc, data, ..
            } => updates.chunk(offset, data, crc).map(|()| None),
            Message::Commit { .. } => updates
                .commit(self.workspace, self.cache, self.depth)
                .map(Some),
            _ => Ok(None),
        };
        match r {
            Err(refusal) => self.send_error(uart, refusal.code, &refusal.text),
            Ok(Some(serving)) => {
                self.status.model = Some(serving);
                let sent = self.send_status(uart, false);
                self.status.model = None;
                sent?;
                uart.flush()?;
                if let Some(u) = self.updates.as_deref_mut() {
                    u.switch();
                }
                Ok(())
            }
            Ok(None) => {
                let (slot, held) = updates.held();
                let seq = self.next_seq();
                self.send(uart, &Message::Upload { seq, slot, held })
            }
        }
    }

    /// Forgets the fault record if `ack` names it (a stale or wrong `ack` changes nothing).
    fn acknowledge(&mut self, ack: Option<u32>) {
        if ack.is_some() && ack == self.fault.map(|f| f.id()) {
            self.fault = None;
            (self.clear_fault)();
        }
    }

    /// Serves until a shutdown message (`Ok`) or a write error (`Err`). Read-side errors
    /// are counted in [`Server::line_errors`] and served through (see the module
    /// documentation).
    pub fn serve<U, L>(
        &mut self,
        uart: &mut U,
        led: &mut L,
        decoder: &mut Decoder,
    ) -> Result<(), U::Error>
    where
        U: Read + Write + ReadReady,
        L: OutputPin,
    {
        let mut last_rx = (self.now)();
        let mut buf = [0u8; 64];
        loop {
            // Each pass is progress: the previous message was handled.
            (self.feed)();
            let ready = match uart.read_ready() {
                Ok(ready) => ready,
                Err(e) => {
                    self.line_error(&e);
                    false
                }
            };
            // `read` only when bytes are there, so the loop keeps checking the idle time.
            let n = if ready {
                match uart.read(&mut buf) {
                    Ok(n) => n,
                    Err(e) => {
                        self.line_error(&e);
                        0
                    }
                }
            } else {
                0
            };
            if n > 0 {
                for &b in buf.get(..n).unwrap_or(&[]) {
                    decoder.push(b);
                    while let Some(event) = decoder.poll() {
                        if self.handle(uart, led, event)? {
                            return Ok(());
                        }
                    }
                }
                last_rx = (self.now)();
            } else if decoder.pending() > 0 && (self.now)().wrapping_sub(last_rx) > self.idle_ticks
            {
                // A partial message and a silent line: give it up and rescan what it held.
                if let Some(e) = decoder.idle() {
                    if self.handle(uart, led, Err(e))? {
                        return Ok(());
                    }
                }
                while let Some(event) = decoder.poll() {
                    if self.handle(uart, led, event)? {
                        return Ok(());
                    }
                }
                last_rx = (self.now)();
            }
        }
    }
}

/// `Debug` as `Display`, for error texts of library errors.
struct Debug<T>(T);

impl<T: core::fmt::Debug> core::fmt::Display for Debug<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{:?}", self.0)
    }
}
