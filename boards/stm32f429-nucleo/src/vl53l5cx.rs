//! A minimal VL53L5CX (8×8 multizone time-of-flight) driver over `embedded-hal` 1.0 I²C: enough to check
//! the sensor, start ranging and read one frame of 64 distances.
//!
//! What is stubbed, and why: the sensor boots without firmware. ST's ULD driver uploads ≈ 84 KB of
//! firmware (a binary blob under ST's licence, not redistributable here) plus a default configuration
//! before the first ranging. [`Vl53l5cx::init`] therefore takes the blob from the caller
//! (`firmware: &[u8]`, written in 32 KiB pages) and does the documented page/boot sequence around it; with
//! an empty blob it reports [`Error::NoFirmware`]. The results layout (block headers, 4 × mm distances,
//! per-zone target status) follows the ULD's `vl53l5cx_get_ranging_data`.

use embedded_hal::i2c::I2c;

/// Zones per frame (8×8 mode).
pub const ZONES: usize = 64;

// The zones' directions: the library's fixed-point table (`latentbki::tof::VL53L5CX_8X8`: 45° × 45°, 8 × 8
// zones row by row, x right, y down, z forward).

/// One frame: distance in millimetres and ULD target status per zone (5 and 9 = valid).
#[derive(Clone, Copy, Debug)]
pub struct ZoneFrame {
    /// Distance (mm) per zone, row by row.
    pub distance_mm: [i16; ZONES],
    /// Target status per zone.
    pub status: [u8; ZONES],
}

impl ZoneFrame {
    /// No returns.
    pub const EMPTY: Self = Self {
        distance_mm: [0; ZONES],
        status: [0; ZONES],
    };

    /// Whether zone `z` holds a valid range.
    pub fn valid(&self, z: usize) -> bool {
        matches!(self.status.get(z), Some(5 | 9)) && self.distance_mm.get(z).is_some_and(|&d| d > 0)
    }
}

/// What a multizone ranging sensor offers the firmware loop (a mock implements it in tests).
pub trait MultizoneRanger {
    /// Transport error.
    type Error;
    /// Whether a new frame is ready.
    fn data_ready(&mut self) -> Result<bool, Self::Error>;
    /// Read the newest frame.
    fn read_frame(&mut self, frame: &mut ZoneFrame) -> Result<(), Self::Error>;
}

/// Driver errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error<E> {
    /// I²C failed.
    I2c(E),
    /// Wrong device id / revision (not a VL53L5CX).
    WrongDevice(u8, u8),
    /// No firmware blob given: ranging cannot start (see the module doc).
    NoFirmware,
    /// A results block was malformed.
    Malformed,
}

const PAGE_SELECT: u16 = 0x7FFF;
const DEVICE_ID: u16 = 0x0000;
const REVISION_ID: u16 = 0x0001;
const UI_CMD_STATUS: u16 = 0x2C00;
const UI_CMD_END: u16 = 0x2FFF;
const DISTANCE_IDX: u16 = 0xD33C;
const TARGET_STATUS_IDX: u16 = 0xD3E8;
/// Bytes of the results buffer with the default outputs in 8×8 mode, one target per zone.
pub const RESULTS_LEN: usize = 1356;

/// A VL53L5CX on an I²C bus.
pub struct Vl53l5cx<I> {
    i2c: I,
    address: u8,
    stream_count: u8,
    buf: [u8; RESULTS_LEN],
}

/// The sensor's default 7-bit address.
pub const DEFAULT_ADDRESS: u8 = 0x29;

impl<I: I2c> Vl53l5cx<I> {
    /// A driver for the sensor at `address`.
    pub const fn new(i2c: I, address: u8) -> Self {
        Self {
            i2c,
            address,
            stream_count: 255,
            buf: [0; RESULTS_LEN],
        }
    }

    fn write(&mut self, reg: u16, data: &[u8]) -> Result<(), Error<I::Error>> {
        let mut frame = [0u8; 2 + 32];
        let mut at = 0;
        // Split long writes so the stack buffer stays small; the index auto-increments.
        while at < data.len() || (at == 0 && data.is_empty()) {
            let n = (data.len() - at).min(32);
            let r = reg.wrapping_add(at as u16).to_be_bytes();
            frame[..2].copy_from_slice(&r);
            frame[2..2 + n].copy_from_slice(&data[at..at + n]);
            self.i2c
                .write(self.address, &frame[..2 + n])
                .map_err(Error::I2c)?;
            at += n;
            if n == 0 {
                break;
            }
        }
        Ok(())
    }

    fn read(&mut self, reg: u16, out: &mut [u8]) -> Result<(), Error<I::Error>> {
        self.i2c
            .write_read(self.address, &reg.to_be_bytes(), out)
            .map_err(Error::I2c)
    }

    /// Check the device id (0xF0) and revision (0x02).
    pub fn is_alive(&mut self) -> Result<(), Error<I::Error>> {
        self.write(PAGE_SELECT, &[0x00])?;
        let (mut id, mut rev) = ([0u8], [0u8]);
        self.read(DEVICE_ID, &mut id)?;
        self.read(REVISION_ID, &mut rev)?;
        self.write(PAGE_SELECT, &[0x02])?;
        if (id[0], rev[0]) != (0xF0, 0x02) {
            return Err(Error::WrongDevice(id[0], rev[0]));
        }
        Ok(())
    }

    /// Upload the firmware blob (ST's, supplied by the caller) page by page and start 8×8 ranging.
    /// Stubbed: the full ULD sequence also loads the default configuration and the NVM calibration; see
    /// the module doc.
    pub fn init(&mut self, firmware: &[u8]) -> Result<(), Error<I::Error>> {
        self.is_alive()?;
        if firmware.is_empty() {
            return Err(Error::NoFirmware);
        }
        for (page, chunk) in firmware.chunks(0x8000).enumerate() {
            self.write(PAGE_SELECT, &[0x09 + page as u8])?;
            self.write(0x0000, chunk)?;
        }
        self.write(PAGE_SELECT, &[0x02])?;
        // Start command (ULD: vl53l5cx_start_ranging writes the command block ending at UI_CMD_END).
        self.write(UI_CMD_END - 3, &[0x00, 0x03, 0x00, 0x00])?;
        Ok(())
    }

    fn parse(&self, frame: &mut ZoneFrame) -> Result<(), Error<I::Error>> {
        // Block headers, big-endian: type (4 bits) | size (12 bits) | index (16 bits); data follows.
        let mut i = 16;
        while i + 4 <= RESULTS_LEN {
            let h = u32::from_be_bytes([
                self.buf[i],
                self.buf[i + 1],
                self.buf[i + 2],
                self.buf[i + 3],
            ]);
            let (kind, size, idx) = (
                (h & 0xF) as usize,
                ((h >> 4) & 0xFFF) as usize,
                (h >> 16) as u16,
            );
            let len = if kind > 1 && kind < 0xD {
                kind * size
            } else {
                size
            };
            let data = self.buf.get(i + 4..i + 4 + len).ok_or(Error::Malformed)?;
            match idx {
                DISTANCE_IDX => {
                    for (z, d) in frame.distance_mm.iter_mut().enumerate() {
                        let raw = data.get(2 * z..2 * z + 2).ok_or(Error::Malformed)?;
                        *d = i16::from_le_bytes([raw[0], raw[1]]) / 4;
                    }
                }
                TARGET_STATUS_IDX => {
                    for (z, s) in frame.status.iter_mut().enumerate() {
                        *s = *data.get(z).ok_or(Error::Malformed)?;
                    }
                }
                _ => {}
            }
            i += 4 + len;
        }
        Ok(())
    }
}

impl<I: I2c> MultizoneRanger for Vl53l5cx<I> {
    type Error = Error<I::Error>;

    fn data_ready(&mut self) -> Result<bool, Self::Error> {
        let mut s = [0u8; 4];
        self.read(UI_CMD_STATUS, &mut s)?;
        // A new frame: the stream count moved and the status says "ready".
        let ready =
            s[0] != 0xFF && s[0] != self.stream_count && s[1] == 0x05 && (s[2] & 0x05) == 0x05;
        if ready {
            self.stream_count = s[0];
        }
        Ok(ready)
    }

    fn read_frame(&mut self, frame: &mut ZoneFrame) -> Result<(), Self::Error> {
        self.i2c
            .write_read(self.address, &0x0000u16.to_be_bytes(), &mut self.buf)
            .map_err(Error::I2c)?;
        // The sensor sends 32-bit words little-endian first: swap to the ULD's byte order.
        for w in self.buf.chunks_exact_mut(4) {
            w.reverse();
        }
        self.parse(frame)
    }
}
