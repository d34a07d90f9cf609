//! The vehicle's serial line as the library's server wants it: `embedded_io` 0.6
//! `Read + Write + ReadReady` over embassy-stm32's interrupt-driven `BufferedUart` (which
//! speaks `embedded-io` 0.7).
//!
//! Line errors (overrun, framing, noise, parity) are not fatal: the bytes are lost, the link
//! decoder resynchronises on the next sync pattern and answers with an error message, exactly
//! as it does for corrupt bytes. They are counted for the log.

use embassy_stm32::usart::{BufferedUart, Error};

/// The link UART.
pub struct Link<'d> {
    uart: BufferedUart<'d>,
    /// Line errors seen since start.
    pub line_errors: u32,
}

impl<'d> Link<'d> {
    /// Wraps a configured buffered UART.
    pub fn new(uart: BufferedUart<'d>) -> Self {
        Self {
            uart,
            line_errors: 0,
        }
    }

    fn line_error(&mut self, e: Error) {
        self.line_errors = self.line_errors.wrapping_add(1);
        defmt::warn!("link UART line error {}", e);
    }
}

impl embedded_io::ErrorType for Link<'_> {
    type Error = core::convert::Infallible;
}

impl embedded_io::ReadReady for Link<'_> {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        match embedded_io_async::ReadReady::read_ready(&mut self.uart) {
            Ok(ready) => Ok(ready),
            Err(e) => {
                self.line_error(e);
                Ok(false)
            }
        }
    }
}

impl embedded_io::Read for Link<'_> {
    /// Blocks until at least one byte is there (`BufferedUart`'s blocking read returns 0 on an
    /// empty ring), then takes what the ring holds.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        if buf.is_empty() {
            return Ok(0);
        }
        loop {
            match embedded_io_07::Read::read(&mut self.uart, buf) {
                Ok(0) => {}
                Ok(n) => return Ok(n),
                Err(e) => self.line_error(e),
            }
        }
    }
}

impl embedded_io::Write for Link<'_> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        // The blocking write only fails on errors it does not report for TX; retry until the
        // ring took something.
        loop {
            match embedded_io_07::Write::write(&mut self.uart, buf) {
                Ok(n) => return Ok(n),
                Err(e) => self.line_error(e),
            }
        }
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        if let Err(e) = embedded_io_07::Write::flush(&mut self.uart) {
            self.line_error(e);
        }
        Ok(())
    }
}
