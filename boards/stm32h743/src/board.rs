//! The STM32H743 board: clocks, caches, cycle counter, busy LED, link UART, stack region, and
//! flash bank 2's driver (the update partition, `crate::update`).
//! The only file that knows the part and the pinout (Nucleo-H743ZI: USART3 on PD8/PD9 is the
//! ST-LINK's virtual COM port, LD1 on PB0); another module changes the pins here.

use core::mem::MaybeUninit;

use cortex_m::peripheral::{DWT, SCB};
use embassy_stm32::flash::{Bank2Region, Blocking, Flash};
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::peripherals::IWDG1;
use embassy_stm32::usart::{self, BufferedUart};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, peripherals};
use epssn_selftest::Stack;

/// Core clock: PLL1 P.
pub const CPU_HZ: u32 = 480_000_000;
/// The link's bit rate, 8N1. The ST-LINK/V3 bridge of the Nucleo-H743ZI2 takes it; the
/// STLINK-V2-1 of the older Nucleo-H743ZI too (it tops out near 2 Mbit/s). A 16 KiB frame takes
/// about 0.18 s at this rate, a depth reply 0.09 s.
pub const LINK_BAUD: u32 = 921_600;
/// The UART rings: RX holds a whole frame message, so no byte is lost while the core
/// computes or answers; TX holds a status or error reply whole.
const RX_RING: usize = 6 + 192 + 16_384 + 4;
const TX_RING: usize = 512;

bind_interrupts!(struct Irqs {
    USART3 => usart::BufferedInterruptHandler<peripherals::USART3>;
});

#[link_section = ".axisram.uart_rx"]
static mut RX_BUF: MaybeUninit<[u8; RX_RING]> = MaybeUninit::uninit();
#[link_section = ".axisram.uart_tx"]
static mut TX_BUF: MaybeUninit<[u8; TX_RING]> = MaybeUninit::uninit();

/// What `main` uses of the board.
pub struct Board {
    /// LD1 (green, PB0), lit while computing a depth map.
    pub busy_led: Output<'static>,
    /// The vehicle's serial line, as the library's server takes it (embedded-io 0.7). Its
    /// blocking read returns `Ok(0)` on an empty ring; the server only reads when
    /// `read_ready`, retries an empty read and counts read errors as line errors.
    pub link: BufferedUart<'static>,
    /// IWDG1, started (see [`WATCHDOG_US`]); fed by the serving loop.
    pub watchdog: IndependentWatchdog<'static, IWDG1>,
    /// RCC_RSR as the reset left it (the flags are cleared for the next reset).
    pub reset_flags: u32,
    /// Flash bank 2 (the update partition), through embassy-stm32's blocking driver.
    pub bank2: Bank2Region<'static, Blocking>,
    /// The system control block, caches enabled: the update partition's D-cache maintenance.
    pub scb: SCB,
}

/// RCC reset status register (RCC base 0x5802_4400 + 0xD0).
const RCC_RSR: usize = 0x5802_44D0;

/// IWDG1 timeout, µs. A depth map costs at most 48 M instructions (weights/budgets.json);
/// at up to 2 cycles each on the 480 MHz core that is 200 ms, and its 8 KiB reply takes 90 ms
/// at 921,600 baud: one pass of the serving loop stays under 300 ms, and each step of the boot
/// self-test is fed at every line it logs. The longest step is an update chunk's erase of one
/// 128 KiB sector of bank 2 (fed before each): seconds, at the parallelism embassy-stm32
/// leaves set after a program; Keil's STM32H7 flash algorithm allows 6 s per sector. Eight
/// seconds cover that with the LSI's ±10 % (RM0433: 29.5–34 kHz).
pub const WATCHDOG_US: u32 = 8_000_000;

/// The clock tree, from the 64 MHz HSI (no dependence on the module's crystal or the ST-LINK's
/// MCO): PLL1 M = 4 (16 MHz reference), N = 60 (VCO 960 MHz, wide range), P = 2 → SYSCLK
/// 480 MHz; AHB /2 = 240 MHz (AXI, flash), APB1–4 /2 = 120 MHz (USART3's kernel clock).
/// 480 MHz needs voltage scale 0 (VOS1 then the SYSCFG overdrive, which embassy sets), the
/// LDO supply (the Nucleo's default) and silicon revision V; revision Y parts stop at 400 MHz
/// (N = 50) and VOS0 limits the junction to 105 °C. Flash wait states follow from the AXI clock
/// (embassy: 2 WS + WRHIGHFREQ 2 at 240 MHz).
fn rcc_config() -> embassy_stm32::Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    config.rcc.hsi = Some(HSIPrescaler::DIV1);
    config.rcc.csi = true;
    config.rcc.pll1 = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL60,
        fracn: None,
        divp: Some(PllDiv::DIV2),
        divq: None,
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV2;
    config.rcc.apb1_pre = APBPrescaler::DIV2;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.apb3_pre = APBPrescaler::DIV2;
    config.rcc.apb4_pre = APBPrescaler::DIV2;
    config.rcc.voltage_scale = VoltageScale::Scale0;
    // The H743's supply (RM0433 PWR) is set to the LDO by embassy's init; no option here.
    config
}

/// Clocks, caches, the cycle counter, the LED and the link UART.
pub fn init() -> Board {
    // SAFETY: RCC_RSR (RM0433 8.7.39), a word register; writing RMVF (bit 16) only clears the
    // reset flags, so the next reset's are its own. Nothing else touches it.
    let reset_flags = unsafe {
        let rsr = RCC_RSR as *mut u32;
        let flags = core::ptr::read_volatile(rsr);
        core::ptr::write_volatile(rsr, flags | 1 << 16);
        flags
    };
    let p = embassy_stm32::init(rcc_config());
    let mut watchdog = IndependentWatchdog::new(p.IWDG1, WATCHDOG_US);
    watchdog.unleash();
    let mut cp = cortex_m::Peripherals::take().expect("core peripherals taken once");
    // Caches for code and constants in flash (weights, warp tables) and the AXI SRAM buffers.
    // Nothing here uses DMA, so the D-cache needs no maintenance; DTCM is never cached.
    cp.SCB.enable_icache();
    cp.SCB.enable_dcache(&mut cp.CPUID);
    // DWT CYCCNT: one count per core cycle. The Cortex-M7 DWT has a software lock that some
    // STM32 parts leave set after a power cycle without a debugger: unlock it first.
    cp.DCB.enable_trace();
    DWT::unlock();
    cp.DWT.set_cycle_count(0);
    cp.DWT.enable_cycle_counter();

    let bank2 = Flash::new_blocking(p.FLASH)
        .into_blocking_regions()
        .bank2_region;
    let busy_led = Output::new(p.PB0, Level::Low, Speed::Low);
    let mut config = usart::Config::default();
    config.baudrate = LINK_BAUD;
    // SAFETY: `init` runs once (the core peripherals' `take` above would panic otherwise);
    // these are the only references to the ring buffers, handed to the driver for good.
    // .axisram is NOLOAD, so each buffer is written before a reference to it exists.
    let (tx_buf, rx_buf) = unsafe {
        (
            (*core::ptr::addr_of_mut!(TX_BUF)).write([0; TX_RING]),
            (*core::ptr::addr_of_mut!(RX_BUF)).write([0; RX_RING]),
        )
    };
    let uart = BufferedUart::new(p.USART3, p.PD9, p.PD8, tx_buf, rx_buf, Irqs, config)
        .expect("USART3 at the link's baud rate");
    Board {
        busy_led,
        link: uart,
        watchdog,
        reset_flags,
        bank2,
        scb: cp.SCB,
    }
}

/// Core cycles since boot (DWT CYCCNT, wraps every 8.9 s at 480 MHz; every user subtracts
/// with wrapping).
pub fn cycles() -> u32 {
    DWT::cycle_count()
}

/// Start of DTCM, the RAM region of memory.x (flip-link puts the stack there).
const RAM_ORIGIN: usize = 0x2000_0000;

/// The stack, for its paint and high-water mark (the implementation every board shares).
pub fn stack() -> Stack {
    // SAFETY: RAM_ORIGIN is the origin of memory.x's RAM region (DTCM), which cortex-m-rt
    // (through flip-link) puts this image's stack in.
    unsafe { Stack::new(RAM_ORIGIN) }
}
