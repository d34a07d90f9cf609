//! The fault record: why the device last reset, kept across the reset in RAM the start-up
//! code does not touch, and reported to the host in the `hello` reply (docs/LINK.md, "Resets
//! and the fault record").
//!
//! The boards only read and write the record's [`RECORD_WORDS`] words and their registers;
//! the layout, the CRC and the validation are here, where host tests reach them. A record is
//! believed only when its magic and its CRC hold, so RAM garbage after a power-on (or a record
//! half written when the reset came) reads as [`ResetCause::PowerOn`], never as a fault.
//!
//! Layout (u32 words, little-endian on the wire, [`RECORD_LEN`] bytes):
//!
//! ```text
//! word  0      MAGIC ("EPFR")
//! word  1      CRC-32 (IEEE) of bytes 8..128
//! word  2      cause (bits 0..8) | text length in bytes (bits 8..16)
//! words 3..10  PC, LR, xPSR (stacked), CFSR, HFSR, MMFAR, BFAR
//! words 10, 11 panic line, column
//! words 12..32 panic text, UTF-8, TEXT_LEN bytes at most
//! ```

use core::fmt;

use crate::crc32::Crc32;

/// Words of a record.
pub const RECORD_WORDS: usize = 32;
/// Bytes of a record (on the wire: the payload of a `hello` reply that carries one).
pub const RECORD_LEN: usize = RECORD_WORDS * 4;
/// Bytes of panic text a record keeps (message, then `@ file`); longer texts are cut.
pub const TEXT_LEN: usize = (RECORD_WORDS - TEXT_WORD) * 4;
/// First word of a valid record: "EPFR" read as u32 LE.
pub const MAGIC: u32 = u32::from_le_bytes(*b"EPFR");
/// First word of the text.
const TEXT_WORD: usize = 12;

/// The faults a test build's `inject` message provokes (feature `fault-injection` of the
/// library and `reset-faults` of the QEMU firmware; `host-sim sil --reset-faults`).
pub mod inject {
    /// The serving loop stops feeding the watchdog: a hang.
    pub const HANG: u16 = 1;
    /// A panic.
    pub const PANIC: u16 = 2;
    /// Unbounded recursion: the stack overflows into the guard below RAM (flip-link).
    pub const STACK_OVERFLOW: u16 = 3;
}

/// Why the device last reset.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetCause {
    /// No valid record: power-on (or a reset nothing recorded, e.g. a debugger's).
    PowerOn = 0,
    /// The watchdog expired: the serving loop stopped making progress.
    Watchdog = 1,
    /// A panic (the record has its text and location).
    Panic = 2,
    /// A HardFault (the record has the stacked registers and the fault status registers).
    HardFault = 3,
    /// A reset the board's reset-cause flags name but no record explains (STM32: the reset
    /// pin, a brown-out, a low-power or window-watchdog reset).
    Other = 4,
}

impl ResetCause {
    /// Every cause, for lookups.
    pub const ALL: [ResetCause; 5] = [
        ResetCause::PowerOn,
        ResetCause::Watchdog,
        ResetCause::Panic,
        ResetCause::HardFault,
        ResetCause::Other,
    ];

    /// The number on the wire (`reset` in the `hello` reply) and in the record.
    pub fn code(self) -> u8 {
        self as u8
    }

    /// The cause of a number.
    pub fn from_code(code: u32) -> Option<Self> {
        Self::ALL
            .iter()
            .copied()
            .find(|c| u32::from(c.code()) == code)
    }

    /// A short name, for reports.
    pub fn name(self) -> &'static str {
        match self {
            ResetCause::PowerOn => "power_on",
            ResetCause::Watchdog => "watchdog",
            ResetCause::Panic => "panic",
            ResetCause::HardFault => "hard_fault",
            ResetCause::Other => "other",
        }
    }
}

/// The cause of an STM32H7's reset from its RCC_RSR flags (RM0433 8.7.39) and the record
/// in RAM. IWDG1 wins (the IWDG has no early interrupt, so no record says `watchdog`); a
/// power-on or brown-out is `PowerOn` whatever the RAM holds; a software reset (SYSRESETREQ:
/// a panic or HardFault handler) is the record's cause; anything else (the reset pin, a
/// window-watchdog or low-power reset, a software reset without a record such as the board's
/// after `shutdown`) is `Other`. The pin flag is set by every reset, so it decides nothing.
pub fn stm32h7_reset_cause(rsr: u32, record: Option<&Record>) -> ResetCause {
    const BORRSTF: u32 = 1 << 21;
    const PORRSTF: u32 = 1 << 23;
    const SFTRSTF: u32 = 1 << 24;
    const IWDG1RSTF: u32 = 1 << 26;
    if rsr & IWDG1RSTF != 0 {
        ResetCause::Watchdog
    } else if rsr & (PORRSTF | BORRSTF) != 0 {
        ResetCause::PowerOn
    } else if rsr & SFTRSTF != 0 {
        record.map_or(ResetCause::Other, |r| r.cause)
    } else {
        ResetCause::Other
    }
}

/// What a fault handler found, written just before it resets the device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Record {
    /// The fault.
    pub cause: ResetCause,
    /// Stacked PC: where the core was (HardFault, watchdog); 0 when unknown.
    pub pc: u32,
    /// Stacked LR.
    pub lr: u32,
    /// Stacked xPSR.
    pub xpsr: u32,
    /// Configurable Fault Status Register (SCB, 0xE000_ED28).
    pub cfsr: u32,
    /// HardFault Status Register (0xE000_ED2C).
    pub hfsr: u32,
    /// MemManage Fault Address Register (0xE000_ED34).
    pub mmfar: u32,
    /// BusFault Address Register (0xE000_ED38).
    pub bfar: u32,
    /// Panic: source line.
    pub line: u32,
    /// Panic: source column.
    pub column: u32,
    text: [u8; TEXT_LEN],
    text_len: u8,
}

impl Record {
    /// A record of `cause` with every register 0 and no text.
    pub const fn new(cause: ResetCause) -> Self {
        Self {
            cause,
            pc: 0,
            lr: 0,
            xpsr: 0,
            cfsr: 0,
            hfsr: 0,
            mmfar: 0,
            bfar: 0,
            line: 0,
            column: 0,
            text: [0; TEXT_LEN],
            text_len: 0,
        }
    }

    /// A panic's record: `message @ file` cut to [`TEXT_LEN`] bytes (at a character
    /// boundary), and the line and column.
    pub fn panic(message: &dyn fmt::Display, file: &str, line: u32, column: u32) -> Self {
        let mut r = Self::new(ResetCause::Panic);
        r.line = line;
        r.column = column;
        let mut text = Text {
            buf: &mut r.text,
            len: 0,
            full: false,
        };
        // `Text` never fails: it drops what does not fit.
        let _ = fmt::write(&mut text, format_args!("{message} @ {file}"));
        r.text_len = text.len as u8;
        r
    }

    /// The panic text (empty for other causes).
    pub fn text(&self) -> &str {
        let n = usize::from(self.text_len).min(TEXT_LEN);
        core::str::from_utf8(self.text.get(..n).unwrap_or(&[])).unwrap_or("")
    }

    /// The record as stored and sent: magic, CRC, fields.
    pub fn to_words(&self) -> [u32; RECORD_WORDS] {
        let mut w = [0u32; RECORD_WORDS];
        w[2] = u32::from(self.cause.code()) | (u32::from(self.text_len) << 8);
        w[3..12].copy_from_slice(&[
            self.pc,
            self.lr,
            self.xpsr,
            self.cfsr,
            self.hfsr,
            self.mmfar,
            self.bfar,
            self.line,
            self.column,
        ]);
        for (word, chunk) in w[TEXT_WORD..].iter_mut().zip(self.text.chunks_exact(4)) {
            *word = u32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]);
        }
        w[0] = MAGIC;
        w[1] = body_crc(&w);
        w
    }

    /// The record of stored words, if the magic, the CRC, the cause and the text hold.
    pub fn from_words(w: &[u32; RECORD_WORDS]) -> Option<Self> {
        if w[0] != MAGIC || w[1] != body_crc(w) {
            return None;
        }
        let cause = ResetCause::from_code(w[2] & 0xFF)?;
        let text_len = (w[2] >> 8) & 0xFF;
        if text_len as usize > TEXT_LEN || w[2] >> 16 != 0 {
            return None;
        }
        let mut r = Self::new(cause);
        [
            r.pc, r.lr, r.xpsr, r.cfsr, r.hfsr, r.mmfar, r.bfar, r.line, r.column,
        ] = [w[3], w[4], w[5], w[6], w[7], w[8], w[9], w[10], w[11]];
        for (chunk, word) in r.text.chunks_exact_mut(4).zip(&w[TEXT_WORD..]) {
            chunk.copy_from_slice(&word.to_le_bytes());
        }
        r.text_len = text_len as u8;
        // A valid CRC over text that is not UTF-8 was never written by `panic`.
        core::str::from_utf8(&r.text[..text_len as usize]).ok()?;
        Some(r)
    }

    /// The record's bytes on the wire (its words, little-endian).
    pub fn to_bytes(&self) -> [u8; RECORD_LEN] {
        let mut b = [0u8; RECORD_LEN];
        for (chunk, word) in b.chunks_exact_mut(4).zip(self.to_words()) {
            chunk.copy_from_slice(&word.to_le_bytes());
        }
        b
    }

    /// The record of received bytes (exactly [`RECORD_LEN`]), if valid.
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        if bytes.len() != RECORD_LEN {
            return None;
        }
        let mut w = [0u32; RECORD_WORDS];
        for (word, chunk) in w.iter_mut().zip(bytes.chunks_exact(4)) {
            *word = u32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]);
        }
        Self::from_words(&w)
    }

    /// The record's identity, which a host's `hello` acknowledges (`ack`): its CRC.
    pub fn id(&self) -> u32 {
        self.to_words()[1]
    }
}

/// CRC-32 of words 2.. as little-endian bytes.
fn body_crc(w: &[u32; RECORD_WORDS]) -> u32 {
    let mut c = Crc32::new();
    for word in &w[2..] {
        c.update(&word.to_le_bytes());
    }
    c.finish()
}

/// A `fmt::Write` into a fixed buffer that keeps what fits, cut at a character boundary:
/// once a character is dropped, everything after it is (no text with a hole in it).
struct Text<'a> {
    buf: &'a mut [u8; TEXT_LEN],
    len: usize,
    full: bool,
}

impl fmt::Write for Text<'_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        for c in s.chars() {
            if self.full {
                break;
            }
            let mut utf8 = [0u8; 4];
            let bytes = c.encode_utf8(&mut utf8).as_bytes();
            let end = self.len + bytes.len();
            match self.buf.get_mut(self.len..end) {
                Some(slot) => {
                    slot.copy_from_slice(bytes);
                    self.len = end;
                }
                None => self.full = true,
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hard_fault() -> Record {
        Record {
            pc: 0x0000_1234,
            lr: 0xFFFF_FFF9,
            xpsr: 0x0100_0003,
            cfsr: 1 << 12,
            hfsr: 1 << 30,
            mmfar: 0xE000_EDF8,
            bfar: 0x1FFF_FFE0,
            ..Record::new(ResetCause::HardFault)
        }
    }

    #[test]
    fn words_round_trip_every_cause() {
        for cause in ResetCause::ALL {
            let r = Record {
                cause,
                ..hard_fault()
            };
            assert_eq!(Record::from_words(&r.to_words()), Some(r));
            assert_eq!(Record::from_bytes(&r.to_bytes()), Some(r));
        }
    }

    #[test]
    fn panic_text_is_message_then_file_and_cut_at_a_char_boundary() {
        let r = Record::panic(&format_args!("index {} out of range", 9), "src/x.rs", 12, 5);
        assert_eq!(r.text(), "index 9 out of range @ src/x.rs");
        assert_eq!((r.line, r.column, r.cause), (12, 5, ResetCause::Panic));
        let back = Record::from_words(&r.to_words()).unwrap();
        assert_eq!(back.text(), r.text());
        // 'é' is two bytes: a message of them cannot end in half of one.
        let long = "é".repeat(TEXT_LEN);
        let r = Record::panic(&long, "f.rs", 1, 1);
        assert_eq!(r.text().len(), TEXT_LEN);
        assert!(r.text().chars().all(|c| c == 'é'));
        let odd = Record::panic(&format_args!("x{long}"), "f.rs", 1, 1);
        assert_eq!(odd.text().len(), TEXT_LEN - 1);
        assert_eq!(Record::from_bytes(&odd.to_bytes()), Some(odd));
    }

    #[test]
    fn zeroed_or_garbage_ram_is_no_record() {
        assert_eq!(Record::from_words(&[0; RECORD_WORDS]), None);
        // A pseudo-random fill, as SRAM holds after power-on: the magic and the CRC must both
        // hold, so none of a thousand fills passes, not even with the magic planted.
        let mut x = 0x1234_5678u32;
        for _ in 0..1000 {
            let mut w = [0u32; RECORD_WORDS];
            for v in w.iter_mut() {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                *v = x;
            }
            assert_eq!(Record::from_words(&w), None);
            w[0] = MAGIC;
            assert_eq!(Record::from_words(&w), None);
        }
    }

    #[test]
    fn any_flipped_bit_invalidates_the_record() {
        let words = Record::panic(&"boom", "src/lib.rs", 3, 9).to_words();
        for i in 0..RECORD_LEN * 8 {
            let mut w = words;
            w[i / 32] ^= 1 << (i % 32);
            assert_eq!(Record::from_words(&w), None, "bit {i}");
        }
    }

    #[test]
    fn valid_crc_over_invalid_fields_is_refused() {
        let refit = |mut w: [u32; RECORD_WORDS]| {
            w[1] = body_crc(&w);
            w
        };
        let mut w = hard_fault().to_words();
        w[2] = 9; // no such cause
        assert_eq!(Record::from_words(&refit(w)), None);
        w[2] = ResetCause::Panic.code() as u32 | ((TEXT_LEN as u32 + 1) << 8);
        assert_eq!(Record::from_words(&refit(w)), None);
        let mut w = Record::panic(&"ab", "c", 1, 1).to_words();
        w[TEXT_WORD] = 0xFFFF_FFFF; // not UTF-8
        assert_eq!(Record::from_words(&refit(w)), None);
        assert_eq!(Record::from_bytes(&[0; RECORD_LEN - 1]), None);
    }

    #[test]
    fn id_is_the_stored_crc_and_differs_between_records() {
        let a = hard_fault();
        let b = Record { pc: a.pc + 2, ..a };
        assert_eq!(a.id(), a.to_words()[1]);
        assert_ne!(a.id(), b.id());
    }

    #[test]
    fn stm32h7_reset_flags_give_the_cause() {
        let (pin, por, bor, sft, iwdg, wwdg) = (
            1u32 << 22,
            1u32 << 23,
            1u32 << 21,
            1u32 << 24,
            1u32 << 26,
            1u32 << 28,
        );
        let panic = Record::panic(&"x", "y", 1, 1);
        let c = stm32h7_reset_cause;
        // Power-on sets POR, BOR and PIN; the RAM may hold anything.
        assert_eq!(c(por | bor | pin, Some(&panic)), ResetCause::PowerOn);
        assert_eq!(c(bor | pin, None), ResetCause::PowerOn);
        assert_eq!(c(iwdg | pin, None), ResetCause::Watchdog);
        assert_eq!(c(iwdg | pin, Some(&panic)), ResetCause::Watchdog);
        assert_eq!(c(sft | pin, Some(&panic)), ResetCause::Panic);
        assert_eq!(c(sft | pin, None), ResetCause::Other);
        assert_eq!(c(pin, Some(&panic)), ResetCause::Other);
        assert_eq!(c(wwdg | pin, None), ResetCause::Other);
    }

    #[test]
    fn cause_codes_round_trip() {
        for c in ResetCause::ALL {
            assert_eq!(ResetCause::from_code(u32::from(c.code())), Some(c));
        }
        assert_eq!(ResetCause::from_code(5), None);
    }
}
