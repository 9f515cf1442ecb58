//! Start the emulated controller (QEMU mps2-an386 running the firmware) and connect to it.
//!
//! The host binds a TCP listener on 127.0.0.1:0 and QEMU connects its UART0 to it, so nothing
//! is lost before the host is ready and no fixed port is needed. The [`Emulator`] guard kills
//! QEMU when dropped, also when a test fails.

use crate::controller::link::{Link, LinkError};
use std::net::TcpListener;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The running emulator; QEMU is killed on drop.
pub struct Emulator {
    child: Child,
}

impl Drop for Emulator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Start QEMU on `elf` with UART0 on the chardev `serial`; `arm_id`: the emulated arm's identity
/// (start option `arm-id=…` on the semihosting command line; default `emulated-arm`).
fn qemu(elf: &Path, serial: &str, arm_id: Option<&str>) -> Result<Emulator, LinkError> {
    if !elf.is_file() {
        return Err(LinkError::Open {
            port: "emulator".into(),
            message: format!(
                "no firmware image at {}: build it with `cargo build-emulated` (needs `rustup target add thumbv7em-none-eabihf`)",
                elf.display()
            ),
        });
    }
    let child = Command::new("qemu-system-arm")
        .args(["-machine", "mps2-an386", "-cpu", "cortex-m4", "-display", "none", "-monitor", "none"])
        .arg("-semihosting-config")
        .arg(match arm_id {
            Some(id) => format!("enable=on,target=native,arg=emulated,arg=arm-id={id}"),
            None => "enable=on,target=native".into(),
        })
        .args(["-serial", serial])
        .arg("-kernel")
        .arg(elf)
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|e| LinkError::Open {
            port: "emulated controller".into(),
            message: format!(
                "cannot start qemu-system-arm ({e}); install it with apt-get install qemu-system-arm"
            ),
        })?;
    Ok(Emulator { child })
}

impl Emulator {
    /// Whether QEMU is still running (it stops on a firmware failure it cannot reset from, or
    /// when killed).
    pub fn running(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }

    /// Start QEMU with UART0 as a TCP server on 127.0.0.1; returns the guard and the port
    /// (`tcp:127.0.0.1:PORT`) to open links to — several in turn, as a serial port.
    pub fn start_server(elf: &Path) -> Result<(Emulator, String), LinkError> {
        Self::start_server_as(elf, None)
    }

    /// [`Emulator::start_server`] with the emulated arm's identity `arm_id` (default
    /// `emulated-arm`): several emulators with their own identities are several arms.
    pub fn start_server_as(elf: &Path, arm_id: Option<&str>) -> Result<(Emulator, String), LinkError> {
        let open_error = |message: String| LinkError::Open { port: "emulated controller".into(), message };
        let port = TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
        let guard = qemu(elf, &format!("tcp:127.0.0.1:{port},server=on,wait=off,nodelay=on"), arm_id)?;
        let deadline = Instant::now() + Duration::from_secs(10);
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            if Instant::now() > deadline {
                return Err(open_error("QEMU did not open its UART port".into()));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        // That probe connection took QEMU's one client slot until it noticed the close.
        std::thread::sleep(Duration::from_millis(100));
        Ok((guard, format!("tcp:127.0.0.1:{port}")))
    }

    /// Start QEMU on `elf` and return the guard with a connected (not yet greeted) link.
    pub fn start(elf: &Path) -> Result<(Emulator, Link), LinkError> {
        Self::start_as(elf, None)
    }

    /// [`Emulator::start`] with the emulated arm's identity `arm_id` (default `emulated-arm`).
    pub fn start_as(elf: &Path, arm_id: Option<&str>) -> Result<(Emulator, Link), LinkError> {
        let open_error = |message: String| LinkError::Open { port: "emulated controller".into(), message };
        let listener = TcpListener::bind("127.0.0.1:0")?;
        let port = listener.local_addr()?.port();
        let guard = qemu(elf, &format!("tcp:127.0.0.1:{port},nodelay=on"), arm_id)?;
        listener.set_nonblocking(true)?;
        let deadline = Instant::now() + Duration::from_secs(10);
        let stream = loop {
            match listener.accept() {
                Ok((s, _)) => break s,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock && Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                Err(e) => return Err(open_error(format!("QEMU did not connect its UART: {e}"))),
            }
        };
        stream.set_nonblocking(false)?;
        stream.set_nodelay(true)?;
        Ok((guard, Link::over(Box::new(stream))))
    }
}
