//! Model updates on a board (docs/UPDATE.md), written once for every board with an update
//! partition: [`BoardUpdates`] is the link server's [`Updates`] over an
//! `epssn_update::Updater` on the board's flash. A commit runs the boot self-test on the new
//! blob in place ([`check_update`]) against the compiled-in key ([`UPDATE_KEY`]), logs its
//! cost, and the switch resets the board, whose boot then serves the journal's model from its
//! slot in place.

use core::fmt::Arguments;

use epssn::config;
use epssn::link::{error_text, Held, Serving};
use epssn::model::Workspace;
use epssn::pairing::FeatureCache;
use epssn::server::{Refusal, Updates};
use epssn_update::{Active, MappedFlash, UpdateError, Updater};
use fixed::types::U16F16;

use crate::{check_update, Clock, UPDATE_KEY};

/// A board's model updates: its partition's updater and what a commit needs of the board.
pub struct BoardUpdates<'a, F> {
    updater: Updater<F>,
    /// Feeds the watchdog (a commit's checks and self-test take a while).
    feed: &'a dyn Fn(),
    /// Resets the board: its boot serves the committed model.
    reset: fn() -> !,
    /// The board's clock: the commit's cost goes to the log.
    clock: Clock<'a>,
    /// The board's console, one line per call.
    log: &'a dyn Fn(Arguments<'_>),
}

impl<'a, F: MappedFlash> BoardUpdates<'a, F> {
    /// The updates of a board whose partition `updater` opened.
    pub fn new(
        updater: Updater<F>,
        feed: &'a dyn Fn(),
        reset: fn() -> !,
        clock: Clock<'a>,
        log: &'a dyn Fn(Arguments<'_>),
    ) -> Self {
        BoardUpdates {
            updater,
            feed,
            reset,
            clock,
            log,
        }
    }

    /// The updater, for a board that reads its flash otherwise (the served blob).
    pub fn updater(&mut self) -> &mut Updater<F> {
        &mut self.updater
    }
}

fn refusal(e: UpdateError) -> Refusal {
    Refusal {
        code: e.code(),
        text: error_text(&e),
    }
}

/// The model that serves, as `hello` and the commit's `status` carry it.
fn serving(a: Active) -> Serving {
    match a {
        Active::Factory => Serving {
            slot: None,
            version: 0,
        },
        Active::Slot { slot, version } => Serving {
            slot: Some(slot),
            version,
        },
    }
}

impl<F: MappedFlash> Updates for BoardUpdates<'_, F> {
    fn serving(&self) -> Serving {
        serving(self.updater.active())
    }

    fn held(&self) -> (u8, Option<Held>) {
        let held = self.updater.upload().map(|u| Held {
            id: u.id,
            version: u.version,
            total: u.total,
            held: u.held,
        });
        (self.updater.upload_slot() as u8, held)
    }

    fn chunk(&mut self, offset: u32, data: &[u8], crc: u32) -> Result<(), Refusal> {
        self.updater
            .chunk(offset, data, crc)
            .map(|_| ())
            .map_err(refusal)
    }

    fn commit(
        &mut self,
        ws: &mut Workspace,
        cache: &mut FeatureCache,
        depth: &mut [U16F16; config::DEPTH_LEN],
    ) -> Result<Serving, Refusal> {
        (self.feed)();
        let (feed, clock) = (self.feed, &self.clock);
        let start = clock.now();
        let checked = core::cell::Cell::new(None);
        let r = self.updater.commit(&UPDATE_KEY, |blob, golden| {
            checked.set(Some(clock.now()));
            // The signature check took its share of the watchdog's period.
            feed();
            check_update(blob, golden, ws, cache, depth)
        });
        let end = clock.now();
        let mid = checked.get().unwrap_or(end);
        let verdict: &dyn core::fmt::Display = match &r {
            Ok(_) => &"switching",
            Err(e) => e,
        };
        (self.log)(format_args!(
            "update commit: checks {} {unit} (blob, signature, version), self-test {} {unit}: {}",
            clock.units(mid.wrapping_sub(start)),
            clock.units(end.wrapping_sub(mid)),
            verdict,
            unit = clock.unit,
        ));
        r.map(serving).map_err(refusal)
    }

    fn switch(&mut self) {
        (self.reset)()
    }
}
