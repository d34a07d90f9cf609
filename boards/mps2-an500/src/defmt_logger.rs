//! A defmt global logger that writes the encoded frames to the semihosting console (decode
//! them with `defmt-print -e target/thumbv7em-none-eabihf/release/epssn-mps2-an500`).

use core::sync::atomic::{AtomicBool, Ordering};

#[defmt::global_logger]
struct Logger;

static TAKEN: AtomicBool = AtomicBool::new(false);
static ENCODER: critical_section::Mutex<core::cell::RefCell<defmt::Encoder>> =
    critical_section::Mutex::new(core::cell::RefCell::new(defmt::Encoder::new()));

fn emit(bytes: &[u8]) {
    if let Ok(mut out) = cortex_m_semihosting::hio::hstdout() {
        let _ = out.write_all(bytes);
    }
}

// SAFETY: the firmware is single-threaded without interrupts that log; `TAKEN` refuses
// re-entrant acquisition.
unsafe impl defmt::Logger for Logger {
    fn acquire() {
        if TAKEN.swap(true, Ordering::Acquire) {
            panic!("defmt logger taken reentrantly");
        }
        critical_section::with(|cs| ENCODER.borrow_ref_mut(cs).start_frame(emit));
    }

    unsafe fn flush() {}

    unsafe fn release() {
        critical_section::with(|cs| ENCODER.borrow_ref_mut(cs).end_frame(emit));
        TAKEN.store(false, Ordering::Release);
    }

    unsafe fn write(bytes: &[u8]) {
        critical_section::with(|cs| ENCODER.borrow_ref_mut(cs).write(bytes, emit));
    }
}

defmt::timestamp!("{=u32}", 0);
