//! The firmware update's state as the device reports it (`/api/status`,
//! Read Device Identification's object 0x80): plain values that the
//! updater (the `update` module, feature `update`) sets and the device keeps,
//! so the device needs nothing of the updater.

/// What the bootloader's state partition says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BootState {
    /// Nothing pending: the running image is confirmed (or was never swapped in).
    Confirmed,
    /// The running image was swapped in and is on trial: the updater
    /// confirms it, or the next reset rolls back to the previous one.
    Trial,
    /// This run armed a swap (the updater's `finish`): the next reset installs it.
    Armed,
    /// The bootloader rolled back: the image swapped in last did not confirm
    /// itself, and the previous one runs again.
    RolledBack,
    /// embassy-boot's USB DFU mark (this device does not use it).
    DfuDetach,
}

/// What `/api/status` and Read Device Identification say about updates:
/// the board sets it on the device at boot
/// ([`Device::set_firmware_update`](super::Device::set_firmware_update)),
/// and the updater when an upload is armed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FirmwareStatus {
    pub state: BootState,
    /// The other image's version (the updater's `other_image`), read at boot.
    pub previous: Option<crate::io::Version>,
    /// The largest update file the device takes.
    pub capacity: u32,
}

impl FirmwareStatus {
    /// The previous firmware's version as Read Device Identification sends
    /// it (object 0x80): empty when unknown.
    pub fn previous_text(&self) -> heapless::String<{ crate::io::Version::MAX_TEXT_LEN }> {
        let mut text = heapless::String::new();
        if let Some(previous) = self.previous {
            // At most 17 bytes (65535.65535.65535): it fits.
            let _ = crate::text::write_version(&mut text, previous);
        }
        text
    }
}

impl BootState {
    /// The state as `/api/status` names it.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Confirmed => "confirmed",
            Self::Trial => "trial",
            Self::Armed => "armed",
            Self::RolledBack => "rolled_back",
            Self::DfuDetach => "dfu_detach",
        }
    }
}
