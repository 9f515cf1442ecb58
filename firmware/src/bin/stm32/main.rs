//! The real controller: STM32F405RG, six BiSS-C encoders on RS-485, USART2 to the host.
//!
//! Pins: USART2 TX PA2 / RX PA3 (to the host's USB-serial adapter, 460800 baud; RX pulled up so
//! an unplugged adapter reads idle, not noise), split: a DMA ring buffer receives every byte
//! while frames are sent. Encoder bus: SPI1 in mode 3 at [`REAL_BOARD_MA_HZ`] (84 MHz APB2 / 64),
//! SCK PA5 drives the encoders' MA through RS-485 transmitters, MISO PA6 reads SLO through their
//! receivers, and PC0…PC5 enable one encoder's transceivers at a time ([`EncoderPort`]). SPI
//! transfers run on DMA2 (RX stream 0, TX stream 3), so the CPU does not wait on bit times.
//! Parameters live in flash sectors 10 and 11 (0x080C0000, 0x080E0000), A/B.
//!
//! Faults: the independent watchdog (IWDG, its own 32 kHz LSI clock) is fed by the sampling
//! loop only ([`WATCHDOG_TIMEOUT_US`]); a panic or a HardFault logs, records its cause in a RAM
//! word that survives the reset ([`kincal_firmware::reset_cause`]) and resets; the next start
//! reports the cause (RCC_CSR flags and that word) in `kincal info`. The ART accelerator
//! (prefetch, instruction and data caches) is switched on after the clock set-up, which clears
//! it. The brown-out level is read and reported, not written (see [`brownout_mv`]).
//! Logging: defmt over RTT (`DEFMT_LOG` is set in `.cargo/config.toml`); `cargo flash-stm32`
//! runs `probe-rs run`, which shows it.
#![no_std]
#![no_main]

mod nor;

use core::cell::RefCell;
use cortex_m_rt::{exception, ExceptionFrame};
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_stm32::gpio::{Level, Output, Pull, Speed};
use embassy_stm32::mode::Async;
use embassy_stm32::spi::{self, Spi};
use embassy_stm32::usart::{self, RingBufferedUartRx, Uart, UartTx};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, peripherals};
use embassy_sync::blocking_mutex::raw::ThreadModeRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_time::Timer;
use embedded_hal_async::spi::{ErrorType, Operation, SpiBus, SpiDevice};
use kincal_firmware::app::{self, Shared, SharedCell, FROM_HOST, TO_HOST};
use kincal_firmware::biss_master::{BissMaster, REAL_BOARD_MA_HZ};
use kincal_firmware::controller::{Action, Controller};
use kincal_firmware::reset_cause::{self, Stm32ResetFlags};
use kincal_firmware::trust::{Trust, BUILD_ARM_ID};
use kincal_protocol::messages::ResetCause;
use nor::Stm32Nor;
use static_cell::StaticCell;

bind_interrupts!(struct Irqs {
    USART2 => usart::InterruptHandler<peripherals::USART2>;
    DMA1_STREAM5 => embassy_stm32::dma::InterruptHandler<peripherals::DMA1_CH5>;
    DMA1_STREAM6 => embassy_stm32::dma::InterruptHandler<peripherals::DMA1_CH6>;
    DMA2_STREAM0 => embassy_stm32::dma::InterruptHandler<peripherals::DMA2_CH0>;
    DMA2_STREAM3 => embassy_stm32::dma::InterruptHandler<peripherals::DMA2_CH3>;
});

/// Watchdog timeout, µs: 4 s on the nominal 32 kHz LSI. The longest time the sampling loop
/// legitimately stops is a sector erase of the parameter log (128 KiB: 1 s typical, 2 s
/// maximum at 32-bit parallelism, F405 datasheet), done only while nothing samples, during
/// which the CPU stalls on flash. The LSI may run at 17–47 kHz, so the real timeout is
/// 2.7–7.5 s: above the 2 s erase in every case. Bring-up: time an erase (defmt logs it) and
/// check `kincal info` reports no watchdog reset after `FlashBusy` was cleared.
const WATCHDOG_TIMEOUT_US: u32 = 4_000_000;

/// Level that enables an encoder's transceivers. The usual RS-485 driver enable (DE, for MA)
/// is active high; check the board's schematic (a shared DE and /RE pin enables the driver and
/// disables the receiver at the same level) — bring-up checklist in the README.
const ENABLE_ACTIVE: Level = Level::High;
/// The other level: transceivers disabled.
const ENABLE_IDLE: Level = match ENABLE_ACTIVE {
    Level::High => Level::Low,
    Level::Low => Level::High,
};
/// Time from enabling an encoder's transceivers to the first MA clock, CPU cycles (2 µs at
/// 168 MHz, busy-waited: shorter than a timer wake): RS-485 drivers and receivers leave high
/// impedance within about 1 µs (check the transceivers' enable times at bring-up).
const ENABLE_SETUP_CYCLES: u32 = 168 * 2;
/// Time MA is held high (driven, transceivers still enabled) after a read, µs: the encoder
/// ends its timeout only after MA has been high for its timeout (typically 20 µs, at most
/// ~40 µs for BiSS-C encoders); an undriven MA would leave that to the line's biasing. An
/// async wait (one timer wake per encoder, about 800 cycles); 0 skips it where the encoders'
/// receivers are fail-safe biased (measured at bring-up).
const ENCODER_TIMEOUT_US: u64 = 40;

type EncoderSpi = Spi<'static, Async, spi::mode::Master>;
type EncoderBus = embassy_sync::mutex::Mutex<ThreadModeRawMutex, EncoderSpi>;

static SHARED: StaticCell<SharedCell<Stm32Nor>> = StaticCell::new();
static ENCODER_BUS: StaticCell<EncoderBus> = StaticCell::new();
static RX_RING: StaticCell<[u8; 1024]> = StaticCell::new();

/// One encoder on the shared SPI1: its enable pin, with the set-up time before the first MA
/// clock and MA held high after the read for the encoder's timeout.
struct EncoderPort {
    bus: &'static EncoderBus,
    enable: Output<'static>,
}

impl ErrorType for EncoderPort {
    type Error = spi::Error;
}

impl SpiDevice for EncoderPort {
    async fn transaction(&mut self, operations: &mut [Operation<'_, u8>]) -> Result<(), spi::Error> {
        let mut bus = self.bus.lock().await;
        self.enable.set_level(ENABLE_ACTIVE);
        cortex_m::asm::delay(ENABLE_SETUP_CYCLES);
        let mut result = Ok(());
        for op in operations.iter_mut() {
            result = match op {
                Operation::Read(buf) => SpiBus::read(&mut *bus, buf).await,
                Operation::Write(buf) => SpiBus::write(&mut *bus, buf).await,
                Operation::Transfer(read, write) => SpiBus::transfer(&mut *bus, read, write).await,
                Operation::TransferInPlace(buf) => SpiBus::transfer_in_place(&mut *bus, buf).await,
                Operation::DelayNs(ns) => {
                    Timer::after_micros((*ns as u64).div_ceil(1000)).await;
                    Ok(())
                }
            };
            if result.is_err() {
                break;
            }
        }
        // SCK idles high in mode 3 (and is pulled up): MA stays high through the timeout.
        if ENCODER_TIMEOUT_US > 0 {
            Timer::after_micros(ENCODER_TIMEOUT_US).await;
        }
        self.enable.set_level(ENABLE_IDLE);
        result
    }
}

#[embassy_executor::task]
async fn sample_encoders(
    shared: &'static SharedCell<Stm32Nor>,
    master: BissMaster<EncoderPort>,
    mut watchdog: IndependentWatchdog<'static, peripherals::IWDG>,
) -> ! {
    app::sample_encoders(shared, master, || watchdog.pet()).await
}

#[embassy_executor::task]
async fn serve_host(shared: &'static SharedCell<Stm32Nor>) -> ! {
    app::serve_host(shared, |action| {
        if action == Action::Reset {
            reset_cause::reset_because(ResetCause::Software);
        }
    })
    .await
}

/// Host → controller: the DMA ring buffer keeps receiving while this task or others run.
#[embassy_executor::task]
async fn receive_from_host(mut rx: RingBufferedUartRx<'static>) -> ! {
    let mut buf = [0u8; 64];
    loop {
        match rx.read(&mut buf).await {
            Ok(n) => {
                let mut rest = &buf[..n];
                while !rest.is_empty() {
                    let k = FROM_HOST.write(rest).await;
                    rest = &rest[k..];
                }
            }
            // Overrun or framing error: the bytes are gone; the host's next frame starts with a
            // delimiter, so only the damaged frame is lost (answered as a bad frame).
            Err(e) => defmt::warn!("host link receive error: {}", e),
        }
    }
}

/// Controller → host.
#[embassy_executor::task]
async fn send_to_host(mut tx: UartTx<'static, Async>) -> ! {
    let mut buf = [0u8; 256];
    loop {
        let n = TO_HOST.read(&mut buf).await;
        if let Err(e) = tx.write(&buf[..n]).await {
            defmt::warn!("host link send error: {}", e);
        }
    }
}

fn clocks() -> embassy_stm32::Config {
    use embassy_stm32::rcc::*;
    use embassy_stm32::time::Hertz;
    let mut config = embassy_stm32::Config::default();
    // 8 MHz crystal → 168 MHz core, APB1 42 MHz (timers 84 MHz: 12 MHz ticks divide it by 7),
    // APB2 84 MHz (SPI1).
    config.rcc.hse = Some(Hse { freq: Hertz(8_000_000), mode: HseMode::Oscillator });
    config.rcc.pll_src = PllSource::HSE;
    config.rcc.pll = Some(Pll {
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL168,
        divp: Some(PllPDiv::DIV2),
        divq: Some(PllQDiv::DIV7),
        divr: None,
    });
    config.rcc.ahb_pre = AHBPrescaler::DIV1;
    config.rcc.apb1_pre = APBPrescaler::DIV4;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.sys = Sysclk::PLL1_P;
    config
}

/// Why this start happened (RCC_CSR's flags, cleared here, and the recorded word).
fn take_reset_cause() -> ResetCause {
    use embassy_stm32::pac::RCC;
    let csr = RCC.csr().read();
    let flags = Stm32ResetFlags {
        independent_watchdog: csr.wdgrstf(),
        software: csr.sftrstf(),
        power_on: csr.porrstf(),
        brown_out: csr.borrstf(),
        pin: csr.padrstf(),
    };
    RCC.csr().modify(|w| w.set_rmvf(true));
    reset_cause::stm32_cause(flags, reset_cause::take_recorded())
}

/// The brown-out reset threshold the option bytes set, mV (falling supply, F405 datasheet).
///
/// Read, not written: the factory setting is "off" (reset only at ~1.8 V), and programming the
/// 32-bit flash words of the parameter log needs at least 2.7 V (BOR level 3). Writing the
/// option bytes at every boot would reprogram the whole option word (read protection and
/// write protection included) on each start, where a power cut could leave them damaged; the
/// level is set once at bring-up instead (probe-rs / STM32CubeProgrammer: BOR_LEV = level 3),
/// and `kincal info` warns while it is below 2.7 V.
fn brownout_mv() -> u16 {
    match embassy_stm32::pac::FLASH.optcr().read().bor_lev() {
        0b00 => 2700,
        0b01 => 2400,
        0b10 => 2100,
        _ => 1800,
    }
}

/// Start the IWDG before anything else, so that clock start-up (a dead crystal spins there)
/// and the boot-time erase are watched too: prescaler /64 and the reload value
/// [`IndependentWatchdog`] sets again later (1999: 4 s). The first period counts down from the
/// reset value 0xFFF (8.2 s at /64); the sampling loop's first feed reloads 4 s.
fn start_watchdog_early() {
    use embassy_stm32::pac::iwdg::vals::{Key, Pr};
    use embassy_stm32::pac::IWDG;
    IWDG.kr().write(|w| w.set_key(Key::ENABLE));
    IWDG.pr().write(|w| w.set_pr(Pr::DIVIDE_BY64));
    IWDG.rlr().write(|w| w.set_rl((WATCHDOG_TIMEOUT_US / 1000 * 32 / 64 - 1) as u16));
    IWDG.kr().write(|w| w.set_key(Key::START));
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let reset = take_reset_cause();
    start_watchdog_early();
    let p = embassy_stm32::init(clocks());
    // The RCC set-up rewrote FLASH_ACR (wait states) and left the ART accelerator off.
    embassy_stm32::pac::FLASH.acr().modify(|w| {
        w.set_prften(true);
        w.set_icen(true);
        w.set_dcen(true);
    });
    let brownout = brownout_mv();
    defmt::info!(
        "kincal controller starting: reset cause {}, brown-out reset below {} mV",
        defmt::Debug2Format(&reset),
        brownout
    );
    if brownout < 2700 {
        defmt::warn!("brown-out level below 2.7 V: flash programming is not protected; set BOR level 3");
    }

    let mut uart_config = usart::Config::default();
    uart_config.baudrate = kincal_protocol::messages::LINK_BAUD;
    uart_config.rx_pull = Pull::Up;
    let Ok(uart) = Uart::new(p.USART2, p.PA3, p.PA2, p.DMA1_CH6, p.DMA1_CH5, Irqs, uart_config) else {
        panic!("USART2 configuration")
    };
    let (tx, rx) = uart.split();
    let rx = rx.into_ring_buffered(RX_RING.init([0; 1024]));

    let mut spi_config = spi::Config::default();
    spi_config.mode = spi::MODE_3;
    spi_config.frequency = embassy_stm32::time::Hertz(REAL_BOARD_MA_HZ);
    // A dead receiver or an unplugged encoder leaves SLO floating: pulled up, it reads as no
    // answer (the line stays high), never as random bits.
    spi_config.miso_pull = Pull::Up;
    let bus: &'static EncoderBus = ENCODER_BUS.init(embassy_sync::mutex::Mutex::new(Spi::new_rxonly(
        p.SPI1, p.PA5, p.PA6, p.DMA2_CH3, p.DMA2_CH0, Irqs, spi_config,
    )));
    // SCK (MA) pulled up as well: high between reads even while SPI1 is disabled.
    embassy_stm32::pac::GPIOA
        .pupdr()
        .modify(|w| w.set_pupdr(5, embassy_stm32::pac::gpio::vals::Pupdr::PULL_UP));
    let port = |pin: embassy_stm32::Peri<'static, embassy_stm32::gpio::AnyPin>| EncoderPort {
        bus,
        enable: Output::new(pin, ENABLE_IDLE, Speed::VeryHigh),
    };
    let master = BissMaster::new([
        port(p.PC0.into()),
        port(p.PC1.into()),
        port(p.PC2.into()),
        port(p.PC3.into()),
        port(p.PC4.into()),
        port(p.PC5.into()),
    ]);

    let mut controller = Controller::new(
        concat!("kincal-fw ", env!("CARGO_PKG_VERSION")),
        "stm32f405",
        false,
        // The arm identity built in (KINCAL_ARM_ID), else the chip's unique 96-bit ID in hex.
        Trust::provisioned(BUILD_ARM_ID.unwrap_or(embassy_stm32::uid::uid_hex()))
            .expect("the build script and the chip give valid identities"),
        Stm32Nor::new(p.FLASH),
    );
    controller.set_boot(reset, brownout);
    defmt::info!("stored parameters: {}", controller.params().is_some());
    // Sampling has not started: the moment to erase the parameter log's spare sector if needed
    // (at most 2 s, within the watchdog's time since it started).
    controller.maintain_flash();
    let mut watchdog = IndependentWatchdog::new(p.IWDG, WATCHDOG_TIMEOUT_US);
    watchdog.unleash();
    watchdog.pet();
    let shared = SHARED.init(Mutex::new(RefCell::new(Shared::new(controller))));
    match (
        sample_encoders(shared, master, watchdog),
        serve_host(shared),
        receive_from_host(rx),
        send_to_host(tx),
    ) {
        (Ok(a), Ok(b), Ok(c), Ok(d)) => {
            spawner.spawn(a);
            spawner.spawn(b);
            spawner.spawn(c);
            spawner.spawn(d);
        }
        _ => panic!("task already spawned"),
    }
}

/// A processor fault (bad memory access, stack overflow): record it and reset.
#[exception]
unsafe fn HardFault(_frame: &ExceptionFrame) -> ! {
    reset_cause::reset_because(ResetCause::Fault)
}

/// A panic: log it, record it and reset (the field behaviour: never a silent hang).
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic: {}", defmt::Display2Format(info));
    reset_cause::reset_because(ResetCause::Panic)
}
