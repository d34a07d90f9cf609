//! A serial port as the SIL's link to a real board (`host-sim sil --serial /dev/ttyACM0`):
//! opened read-write and put in raw 8N1 mode at the given baud rate with termios (Linux and
//! other Unix systems), blocking reads of at least one byte.

use std::fs::{File, OpenOptions};
use std::os::fd::AsRawFd;
use std::path::Path;

use anyhow::{bail, Context, Result};

/// The termios speed constant of a baud rate.
fn speed(baud: u32) -> Result<libc::speed_t> {
    Ok(match baud {
        9_600 => libc::B9600,
        19_200 => libc::B19200,
        38_400 => libc::B38400,
        57_600 => libc::B57600,
        115_200 => libc::B115200,
        230_400 => libc::B230400,
        #[cfg(target_os = "linux")]
        460_800 => libc::B460800,
        #[cfg(target_os = "linux")]
        921_600 => libc::B921600,
        #[cfg(target_os = "linux")]
        1_000_000 => libc::B1000000,
        #[cfg(target_os = "linux")]
        2_000_000 => libc::B2000000,
        #[cfg(target_os = "linux")]
        4_000_000 => libc::B4000000,
        _ => bail!("baud rate {baud} is not one termios knows here"),
    })
}

/// Puts an open terminal in raw 8N1 mode at `baud`, reads blocking for one byte at least, and
/// discards what was pending in both directions.
pub fn configure(file: &File, baud: u32) -> Result<()> {
    let fd = file.as_raw_fd();
    let speed = speed(baud)?;
    // SAFETY: `fd` is an open descriptor owned by `file` for the whole call; `tio` is a plain C
    // struct that tcgetattr fills before it is read.
    unsafe {
        let mut tio: libc::termios = std::mem::zeroed();
        if libc::tcgetattr(fd, &mut tio) != 0 {
            return Err(std::io::Error::last_os_error()).context("tcgetattr (not a terminal?)");
        }
        libc::cfmakeraw(&mut tio);
        tio.c_cflag |= libc::CLOCAL | libc::CREAD;
        tio.c_cflag &= !(libc::CSTOPB | libc::PARENB | libc::CRTSCTS);
        tio.c_cc[libc::VMIN] = 1;
        tio.c_cc[libc::VTIME] = 0;
        if libc::cfsetispeed(&mut tio, speed) != 0 || libc::cfsetospeed(&mut tio, speed) != 0 {
            return Err(std::io::Error::last_os_error()).context("cfsetspeed");
        }
        if libc::tcsetattr(fd, libc::TCSANOW, &tio) != 0 {
            return Err(std::io::Error::last_os_error()).context("tcsetattr");
        }
        libc::tcflush(fd, libc::TCIOFLUSH);
    }
    Ok(())
}

/// Opens `path` (a serial port, e.g. the ST-LINK's virtual COM port `/dev/ttyACM0`) in raw mode
/// at `baud`.
pub fn open(path: &Path, baud: u32) -> Result<File> {
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        .with_context(|| format!("opening serial port {}", path.display()))?;
    configure(&file, baud).with_context(|| format!("configuring {}", path.display()))?;
    Ok(file)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read, Write};
    use std::os::fd::FromRawFd;

    /// A pseudo-terminal pair: (controller, the device side's path).
    fn pty() -> (File, std::path::PathBuf) {
        // SAFETY: posix_openpt/grantpt/unlockpt/ptsname_r on a fresh descriptor we own; the
        // name buffer outlives the call.
        unsafe {
            let fd = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY);
            assert!(fd >= 0, "posix_openpt");
            assert_eq!(libc::grantpt(fd), 0);
            assert_eq!(libc::unlockpt(fd), 0);
            let mut name = [0 as libc::c_char; 128];
            assert_eq!(libc::ptsname_r(fd, name.as_mut_ptr(), name.len()), 0);
            let path = std::ffi::CStr::from_ptr(name.as_ptr())
                .to_string_lossy()
                .into_owned();
            (File::from_raw_fd(fd), path.into())
        }
    }

    #[test]
    fn raw_mode_passes_every_byte_both_ways() {
        let (mut controller, path) = pty();
        let mut port = open(&path, 921_600).unwrap();
        // Every byte value, including the ones a cooked terminal would interpret (CR, ^C,
        // ^D, XON/XOFF, 0xFF): the link's binary payloads must arrive untouched.
        let all: Vec<u8> = (0..=255u8).cycle().take(1024).collect();
        port.write_all(&all).unwrap();
        let mut got = vec![0u8; all.len()];
        controller.read_exact(&mut got).unwrap();
        assert_eq!(got, all);
        controller.write_all(&all).unwrap();
        let mut back = vec![0u8; all.len()];
        port.read_exact(&mut back).unwrap();
        assert_eq!(back, all);
    }

    #[test]
    fn unknown_baud_and_non_terminal_are_refused() {
        let (_controller, path) = pty();
        assert!(open(&path, 12_345).is_err());
        let not_a_tty = tempfile_path();
        std::fs::write(&not_a_tty, b"x").unwrap();
        assert!(open(&not_a_tty, 921_600).is_err());
        let _ = std::fs::remove_file(&not_a_tty);
    }

    fn tempfile_path() -> std::path::PathBuf {
        std::env::temp_dir().join(format!("epssn-serial-test-{}", std::process::id()))
    }
}
