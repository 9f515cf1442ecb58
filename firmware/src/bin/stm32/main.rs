//! The real controller: STM32F405RG, six BiSS-C encoders on RS-485, USART2 to the host.
//!
//! Pins: USART2 TX PA2 / RX PA3 (to the host's USB-serial adapter, 460800 baud). Encoder bus:
//! the six encoders share one MA (clock) line driven by an RS-485 transmitter (MA on PB0, its
//! driver enable on PB1); each encoder's SLO (data) comes back through its own receiver on
//! PC0…PC5, so all six are clocked and read in the same cycle (synchronous sampling).
//! Parameters live in flash sectors 10 and 11 (0x080C0000, 0x080E0000), A/B.
#![no_std]
#![no_main]

mod bus;
mod nor;

use bus::Rs485Bus;
use core::cell::RefCell;
use embassy_executor::Spawner;
use embassy_stm32::usart::{self, Uart};
use embassy_stm32::{bind_interrupts, peripherals};
use embassy_sync::blocking_mutex::Mutex;
use kincal_firmware::app::{self, Shared, SharedCell, FROM_HOST, TO_HOST};
use kincal_firmware::controller::{Action, Controller};
use kincal_firmware::encoders::Sampler;
use nor::Stm32Nor;
use panic_halt as _;

bind_interrupts!(struct Irqs {
    USART2 => usart::InterruptHandler<peripherals::USART2>;
    DMA1_STREAM5 => embassy_stm32::dma::InterruptHandler<peripherals::DMA1_CH5>;
    DMA1_STREAM6 => embassy_stm32::dma::InterruptHandler<peripherals::DMA1_CH6>;
});

static SHARED: SharedCell<Stm32Nor, Rs485Bus> = Mutex::new(RefCell::new(None));

#[embassy_executor::task]
async fn sample_encoders() -> ! {
    app::sample_encoders(&SHARED).await
}

#[embassy_executor::task]
async fn serve_host() -> ! {
    app::serve_host(&SHARED, |action, _bus| {
        if action == Action::Reset {
            cortex_m::peripheral::SCB::sys_reset();
        }
    })
    .await
}

#[embassy_executor::task]
async fn host_link(mut uart: Uart<'static, embassy_stm32::mode::Async>) -> ! {
    let mut rx = [0u8; 1];
    let mut tx = [0u8; 256];
    loop {
        // Whichever comes first: a byte from the host, or bytes to send.
        match embassy_futures::select::select(uart.read(&mut rx), TO_HOST.read(&mut tx)).await {
            embassy_futures::select::Either::First(Ok(())) => {
                let _ = FROM_HOST.try_write(&rx);
            }
            embassy_futures::select::Either::First(Err(_)) => {}
            embassy_futures::select::Either::Second(n) => {
                let _ = uart.write(&tx[..n]).await;
            }
        }
    }
}

fn clocks() -> embassy_stm32::Config {
    use embassy_stm32::rcc::*;
    use embassy_stm32::time::Hertz;
    let mut config = embassy_stm32::Config::default();
    // 8 MHz crystal → 168 MHz core, APB1 42 MHz (timers 84 MHz: 12 MHz ticks divide it by 7).
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
    uart_config.baudrate = 460_800;
    let Ok(uart) = Uart::new(p.USART2, p.PA3, p.PA2, p.DMA1_CH6, p.DMA1_CH5, Irqs, uart_config) else {
        panic!("USART2 configuration")
    };
    let bus = Rs485Bus::new(
        p.PB0,
        p.PB1,
        [p.PC0.into(), p.PC1.into(), p.PC2.into(), p.PC3.into(), p.PC4.into(), p.PC5.into()],
    );
    let controller = Controller::new(
        concat!("kincal-fw ", env!("CARGO_PKG_VERSION")),
        "stm32f405",
        false,
        Stm32Nor::new(p.FLASH),
    );
    SHARED.lock(|s| *s.borrow_mut() = Some(Shared { controller, sampler: Sampler::default(), bus }));
    match (sample_encoders(), serve_host(), host_link(uart)) {
        (Ok(a), Ok(b), Ok(c)) => {
            spawner.spawn(a);
            spawner.spawn(b);
            spawner.spawn(c);
        }
        _ => panic!("task already spawned"),
    }
}
