//! The fault record's RAM and the handlers that fill it before resetting the device, shared by
//! every board: the record's layout, CRC and validation are the library's
//! (`epssn::fault`); this module only reads and writes its words and the core's fault
//! registers.
//!
//! The record lives in `.uninit` (cortex-m-rt: `NOLOAD`, after `.bss`, never zeroed by the
//! start-up code), so it survives a SYSRESETREQ or a watchdog reset. A panic or a HardFault
//! writes it and resets at once (SYSRESETREQ): the device never halts. The watchdog's own
//! record is written by the board (the QEMU firmware's NMI on the watchdog's first timeout goes
//! through the same entry, `epssn_fault_entry`, as HardFault; the STM32's IWDG has no early interrupt and is told apart
//! by RCC_RSR).
//!
//! Both boards put the stack at 0x2000_0000 (flip-link: below the statics; QEMU's RAM, the
//! STM32H743's DTCM), so an exception frame below [`STACK_ORIGIN`] is one whose stacking
//! faulted: a stack overflow.

use core::mem::MaybeUninit;
use core::ptr::{addr_of_mut, read_volatile, write_volatile};

use epssn::fault::{Record, ResetCause, RECORD_WORDS};

/// Lowest stack address of every board's memory map.
pub const STACK_ORIGIN: u32 = 0x2000_0000;

/// The record's words. `MaybeUninit`: after a power-on they are whatever the SRAM holds.
#[link_section = ".uninit.epssn_fault_record"]
static mut RECORD: MaybeUninit<[u32; RECORD_WORDS]> = MaybeUninit::uninit();

fn word_ptr(i: usize) -> *mut u32 {
    // In bounds: callers pass i < RECORD_WORDS. No reference to the static is formed.
    addr_of_mut!(RECORD).cast::<u32>().wrapping_add(i)
}

/// The record left by the last reset, if its magic and CRC hold.
pub fn stored() -> Option<Record> {
    let mut w = [0u32; RECORD_WORDS];
    for (i, v) in w.iter_mut().enumerate() {
        // SAFETY: `word_ptr(i)` is an aligned word of the static; volatile because the
        // start-up code never wrote it (any bit pattern is a valid u32).
        *v = unsafe { read_volatile(word_ptr(i)) };
    }
    Record::from_words(&w)
}

/// Stores `record`, body first and the magic last, so a reset halfway leaves no valid record.
pub fn store(record: &Record) {
    let w = record.to_words();
    for i in (0..RECORD_WORDS).rev() {
        // SAFETY: as in `stored`; single-threaded, or in a handler that never returns.
        unsafe { write_volatile(word_ptr(i), w[i]) };
    }
}

/// Forgets the record (the host acknowledged it): the magic is cleared.
pub fn clear() {
    // SAFETY: as in `store`.
    unsafe { write_volatile(word_ptr(0), 0) };
}

/// Records a panic (message and location, cut to the record's text) and resets.
pub fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
    let (file, line, column) = info
        .location()
        .map_or(("?", 0, 0), |l| (l.file(), l.line(), l.column()));
    store(&Record::panic(&info.message(), file, line, column));
    cortex_m::peripheral::SCB::sys_reset()
}

/// Reads a System Control Block fault register.
fn scb(addr: u32) -> u32 {
    // SAFETY: the fault status and address registers of the Cortex-M7 SCB (0xE000_ED28..3C),
    // readable at any privilege the firmware runs at.
    unsafe { read_volatile(addr as *const u32) }
}

/// Where [`fault_entry`] lands, on a fresh stack: records the fault and resets.
#[no_mangle]
extern "C" fn epssn_fault(cause: u32, lr: u32, pc: u32, xpsr: u32) -> ! {
    let cause = if cause == ResetCause::Watchdog as u32 {
        ResetCause::Watchdog
    } else {
        ResetCause::HardFault
    };
    let mut r = Record::new(cause);
    (r.pc, r.lr, r.xpsr) = (pc, lr, xpsr);
    r.cfsr = scb(0xE000_ED28);
    r.hfsr = scb(0xE000_ED2C);
    r.mmfar = scb(0xE000_ED34);
    r.bfar = scb(0xE000_ED38);
    store(&r);
    cortex_m::peripheral::SCB::sys_reset()
}

// The common entry of HardFault and the board's watchdog NMI (cause in r0). It touches no
// stack before it has a valid one: after a stack overflow MSP points below the RAM, and any
// push there would fault again inside HardFault (lockup; QEMU aborts). It reads the stacked
// LR, PC and xPSR only when the frame lies within the stack, then restarts the stack at its
// top (the initial MSP, word 0 of the vector table) and branches to `epssn_fault`, which
// never returns.
core::arch::global_asm!(
    ".section .text.epssn_fault_entry,\"ax\",%progbits",
    ".global epssn_fault_entry",
    ".type epssn_fault_entry,%function",
    ".thumb_func",
    "epssn_fault_entry:",
    "    mrs r12, MSP",
    "    movs r1, #0",
    "    movs r2, #0",
    "    movs r3, #0",
    "    ldr r4, =0xE000ED08",
    "    ldr r4, [r4]",
    "    ldr r4, [r4]",
    "    ldr r5, ={origin}",
    "    cmp r12, r5",
    "    blo 1f",
    "    add r5, r12, #32",
    "    cmp r5, r4",
    "    bhi 1f",
    "    ldr r1, [r12, #20]",
    "    ldr r2, [r12, #24]",
    "    ldr r3, [r12, #28]",
    "1:",
    "    mov sp, r4",
    "    b epssn_fault",
    "    .ltorg",
    ".size epssn_fault_entry, . - epssn_fault_entry",
    // HardFault itself (cortex-m-rt's vector table names it; this replaces its trampoline).
    ".section .text.HardFault,\"ax\",%progbits",
    ".global HardFault",
    ".type HardFault,%function",
    ".thumb_func",
    "HardFault:",
    "    movs r0, #{hard_fault}",
    "    b epssn_fault_entry",
    ".size HardFault, . - HardFault",
    origin = const STACK_ORIGIN,
    hard_fault = const ResetCause::HardFault as u32,
);
