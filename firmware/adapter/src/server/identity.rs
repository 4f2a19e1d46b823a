//! Read Device Identification (function 2B, MEI type 0E; Modbus Application
//! Protocol V1.1b3, 6.21): the device's objects, and the answer to a request.
//!
//! | id | object | value |
//! |---|---|---|
//! | 0 | VendorName | [`VENDOR_NAME`] |
//! | 1 | ProductCode | [`PRODUCT_CODE`] |
//! | 2 | MajorMinorRevision | this firmware's version, [`crate::VERSION_TEXT`] |
//! | 3 | VendorUrl | [`VENDOR_URL`] |
//! | 4 | ProductName | [`PRODUCT_NAME`] |
//! | 5 | ModelName | the board ([`Identity::model`]) |
//! | 6 | UserApplicationName | the device name in force ([`Identity::name`]) |
//! | 0x80 | previous firmware (private; images with `update` only) | the other image's version, empty when unknown ([`Identity::previous_firmware`]) |
//!
//! Conformity level 0x82: the basic and regular objects, by stream (codes
//! 01 and 02) and one at a time (code 04); 03, the extended stream, is
//! refused (exception 03) as there are no extended objects. With the
//! previous firmware's object, 0x83: the extended stream too. Every object
//! fits one response: see [`EXTENDED_SET_MAX_LEN`].

use crate::modbus::Exception;
use crate::modbus::identification::{ReadDeviceIdCode, Writer, object};
use crate::modbus::mbap::MAX_PDU_LEN;
use crate::name::{MAX_NAME_LEN, Name};

/// VendorName (object 0). The project is its own vendor.
pub const VENDOR_NAME: &str = "mbio";
/// ProductCode (object 1).
pub const PRODUCT_CODE: &str = "mbio-tcp-io";
/// VendorUrl (object 3): empty, as the project has no web address to give;
/// the object is still there, with no bytes (length 0).
pub const VENDOR_URL: &str = "";
/// ProductName (object 4).
pub const PRODUCT_NAME: &str = "Modbus TCP I/O adapter";
/// The longest ModelName sent; a longer board name is cut to it.
pub const MAX_MODEL_LEN: usize = 32;
/// The conformity level: regular identification, stream and individual
/// access (6.21).
pub const CONFORMITY_LEVEL: u8 = 0x82;
/// The conformity level with the extended object: extended identification,
/// stream and individual access.
pub const EXTENDED_CONFORMITY_LEVEL: u8 = 0x83;
/// The private object with the previous firmware's version.
pub const PREVIOUS_FIRMWARE: u8 = object::FIRST_EXTENDED;
/// The longest version text (`65535.65535.65535`).
pub const MAX_VERSION_LEN: usize = crate::io::Version::MAX_TEXT_LEN;

/// The longest response to a stream of the regular set (code 02 from object
/// 0): the header, then all seven objects at their longest.
pub const REGULAR_SET_MAX_LEN: usize = crate::modbus::identification::HEADER_LEN
    + 7 * crate::modbus::identification::OBJECT_HEADER_LEN
    + VENDOR_NAME.len()
    + PRODUCT_CODE.len()
    + crate::VERSION_TEXT.len()
    + VENDOR_URL.len()
    + PRODUCT_NAME.len()
    + MAX_MODEL_LEN
    + MAX_NAME_LEN;

/// The longest response to an extended stream: the regular set and the
/// previous firmware's object.
pub const EXTENDED_SET_MAX_LEN: usize =
    REGULAR_SET_MAX_LEN + crate::modbus::identification::OBJECT_HEADER_LEN + MAX_VERSION_LEN;

// Every set fits one PDU, so no response has "more follows": each ends
// with the category's last object, more follows 00 and next object id 00
// (6.21), and a client never needs a second request.
const _: () = assert!(EXTENDED_SET_MAX_LEN <= MAX_PDU_LEN);

/// Who the device is: what Read Device Identification answers beyond the
/// constants. Borrowed for one request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity<'a> {
    /// The board: `nucleo-f429zi`, `mps2-an386`, `hal-sim`.
    pub model: &'a str,
    /// The device name in force (the `device.name` setting, or its default
    /// from the MAC): at most [`MAX_NAME_LEN`] bytes.
    pub name: &'a Name,
    /// The previous firmware's version (at most [`MAX_VERSION_LEN`] bytes,
    /// empty when unknown), on a device that takes updates; `None`: no such
    /// object, and no extended objects at all.
    pub previous_firmware: Option<&'a [u8]>,
}

impl<'a> Identity<'a> {
    /// The value of object `id`, or `None` if the device has no such object.
    pub fn object(&self, id: u8) -> Option<&'a [u8]> {
        let text = match id {
            object::VENDOR_NAME => VENDOR_NAME,
            object::PRODUCT_CODE => PRODUCT_CODE,
            object::MAJOR_MINOR_REVISION => crate::VERSION_TEXT,
            object::VENDOR_URL => VENDOR_URL,
            object::PRODUCT_NAME => PRODUCT_NAME,
            object::MODEL_NAME => return Some(clipped(self.model, MAX_MODEL_LEN)),
            object::USER_APPLICATION_NAME => return Some(self.name.as_bytes()),
            PREVIOUS_FIRMWARE => return self.previous_firmware.map(|v| v.get(..MAX_VERSION_LEN).unwrap_or(v)),
            _ => return None,
        };
        Some(text.as_bytes())
    }

    /// Writes the response to a request for `code` from `object_id` into
    /// `out` (a reply's PDU); returns its length.
    ///
    /// A stream (01: objects 0-2, 02: objects 0-6, 03: those and 0x80)
    /// starts at `object_id` when it is one of the category's objects, and
    /// at 0 otherwise ("as if object 0 were pointed out", 6.21); 03 is
    /// exception 03 on a device with no extended object. Code 04 answers
    /// the one object, or exception 02 when the device has none of that id.
    // Out of line: inlined into the session task, it costs 200 bytes more
    // flash on the NUCLEO (measured).
    #[inline(never)]
    pub fn respond(&self, code: ReadDeviceIdCode, object_id: u8, out: &mut [u8]) -> Result<usize, Exception> {
        let (first, last) = match code {
            ReadDeviceIdCode::Basic | ReadDeviceIdCode::Regular | ReadDeviceIdCode::Extended => {
                let last = match code {
                    ReadDeviceIdCode::Basic => object::LAST_BASIC,
                    ReadDeviceIdCode::Regular => object::LAST_REGULAR,
                    _ if self.previous_firmware.is_some() => PREVIOUS_FIRMWARE,
                    _ => return Err(Exception::IllegalDataValue),
                };
                let known = object_id <= last && self.object(object_id).is_some();
                (if known { object_id } else { 0 }, last)
            }
            ReadDeviceIdCode::Specific => match self.object(object_id) {
                Some(_) => (object_id, object_id),
                None => return Err(Exception::IllegalDataAddress),
            },
            // The parser lets no other code through.
            ReadDeviceIdCode::Unknown(_) => return Err(Exception::IllegalDataValue),
        };
        let mut writer = Writer::new(out).ok_or(Exception::ServerDeviceFailure)?;
        // The ids between the regular and the extended objects are reserved: skipped.
        for (id, value) in (first..=last).filter_map(|id| Some((id, self.object(id)?))) {
            writer.push(id, value).ok_or(Exception::ServerDeviceFailure)?;
        }
        let conformity = if self.previous_firmware.is_some() { EXTENDED_CONFORMITY_LEVEL } else { CONFORMITY_LEVEL };
        Ok(writer.finish(code, conformity, None))
    }
}

/// `text`'s first `max` bytes.
fn clipped(text: &str, max: usize) -> &[u8] {
    let bytes = text.as_bytes();
    bytes.get(..max).unwrap_or(bytes)
}
