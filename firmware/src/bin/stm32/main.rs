//! The real controller: STM32F405RG, six BiSS-C encoders on RS-485, USART2 to the host.
//!
//! Pins: USART2 TX PA2 / RX PA3 (to the host's USB-serial adapter, 460800 baud), split: a
//! DMA ring buffer receives every byte while frames are sent. Encoder bus: SPI1 in mode 3 at
//! 5.25 MHz (84 MHz APB2 / 16), SCK PA5 drives the encoders' MA through RS-485 transmitters,
//! MISO PA6 reads SLO through their receivers, and PC0…PC5 select one encoder at a time
//! (active low: that encoder's MA driver and SLO receiver enabled). SPI transfers run on DMA2
//! (RX stream 0, TX stream 3), so the CPU does not wait on bit times.
//! Parameters live in flash sectors 10 and 11 (0x080C0000, 0x080E0000), A/B.
//! Logging: defmt over RTT; panics print through panic-probe (`cargo flash-stm32` runs
//! `probe-rs run`, which shows both).
#![no_std]
#![no_main]

mod nor;

use core::cell::RefCell;
use defmt_rtt as _;
use embassy_embedded_hal::shared_bus::asynch::spi::SpiDevice;
use embassy_executor::Spawner;
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::mode::Async;
use embassy_stm32::spi::{self, Spi};
use embassy_stm32::usart::{self, RingBufferedUartRx, Uart, UartTx};
use embassy_stm32::{bind_interrupts, peripherals};
use embassy_sync::blocking_mutex::raw::ThreadModeRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use kincal_firmware::app::{self, Shared, SharedCell, FROM_HOST, TO_HOST};
use kincal_firmware::biss_master::{BissMaster, REAL_BOARD_MA_HZ};
use kincal_firmware::controller::{Action, Controller};
use kincal_firmware::trust::{Trust, BUILD_ARM_ID};
use nor::Stm32Nor;
use panic_probe as _;
use static_cell::StaticCell;

bind_interrupts!(struct Irqs {
    USART2 => usart::InterruptHandler<peripherals::USART2>;
    DMA1_STREAM5 => embassy_stm32::dma::InterruptHandler<peripherals::DMA1_CH5>;
    DMA1_STREAM6 => embassy_stm32::dma::InterruptHandler<peripherals::DMA1_CH6>;
    DMA2_STREAM0 => embassy_stm32::dma::InterruptHandler<peripherals::DMA2_CH0>;
    DMA2_STREAM3 => embassy_stm32::dma::InterruptHandler<peripherals::DMA2_CH3>;
});

type EncoderSpi = Spi<'static, Async, spi::mode::Master>;
type EncoderBus = embassy_sync::mutex::Mutex<ThreadModeRawMutex, EncoderSpi>;
type Encoder = SpiDevice<'static, ThreadModeRawMutex, EncoderSpi, Output<'static>>;

static SHARED: StaticCell<SharedCell<Stm32Nor>> = StaticCell::new();
static ENCODER_BUS: StaticCell<EncoderBus> = StaticCell::new();
static RX_RING: StaticCell<[u8; 1024]> = StaticCell::new();

#[embassy_executor::task]
async fn sample_encoders(shared: &'static SharedCell<Stm32Nor>, master: BissMaster<Encoder>) -> ! {
    app::sample_encoders(shared, master).await
}

#[embassy_executor::task]
async fn serve_host(shared: &'static SharedCell<Stm32Nor>) -> ! {
    app::serve_host(shared, |action| {
        if action == Action::Reset {
            cortex_m::peripheral::SCB::sys_reset();
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

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clocks());
    let mut uart_config = usart::Config::default();
    uart_config.baudrate = kincal_protocol::messages::LINK_BAUD;
    let Ok(uart) = Uart::new(p.USART2, p.PA3, p.PA2, p.DMA1_CH6, p.DMA1_CH5, Irqs, uart_config) else {
        panic!("USART2 configuration")
    };
    let (tx, rx) = uart.split();
    let rx = rx.into_ring_buffered(RX_RING.init([0; 1024]));

    let mut spi_config = spi::Config::default();
    spi_config.mode = spi::MODE_3;
    spi_config.frequency = embassy_stm32::time::Hertz(REAL_BOARD_MA_HZ);
    let bus: &'static EncoderBus = ENCODER_BUS.init(embassy_sync::mutex::Mutex::new(Spi::new_rxonly(
        p.SPI1, p.PA5, p.PA6, p.DMA2_CH3, p.DMA2_CH0, Irqs, spi_config,
    )));
    let select = |pin: embassy_stm32::Peri<'static, embassy_stm32::gpio::AnyPin>| {
        SpiDevice::new(bus, Output::new(pin, Level::High, Speed::VeryHigh))
    };
    let master = BissMaster::new([
        select(p.PC0.into()),
        select(p.PC1.into()),
        select(p.PC2.into()),
        select(p.PC3.into()),
        select(p.PC4.into()),
        select(p.PC5.into()),
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
    defmt::info!("kincal controller up; stored parameters: {}", controller.params().is_some());
    // Sampling has not started: the moment to erase the parameter log's spare sector if needed.
    controller.maintain_flash();
    let shared = SHARED.init(Mutex::new(RefCell::new(Shared::new(controller))));
    match (sample_encoders(shared, master), serve_host(shared), receive_from_host(rx), send_to_host(tx)) {
        (Ok(a), Ok(b), Ok(c), Ok(d)) => {
            spawner.spawn(a);
            spawner.spawn(b);
            spawner.spawn(c);
            spawner.spawn(d);
        }
        _ => panic!("task already spawned"),
    }
}
