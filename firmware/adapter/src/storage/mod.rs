//! Settings that live on the device (DEVICE.md section 1), over any
//! `embedded-storage-async` NOR flash a board gives.
//!
//! - [`record`]: the settings record, text lines `group.field=value`,
//!   taken whole or not at all.
//! - [`password`]: [`PasswordHash`](password::PasswordHash), the admin
//!   password as PBKDF2-HMAC-SHA256 with a salt.
//! - [`flash`]: [`RuleFlash`](flash::RuleFlash), a NOR flash with real flash
//!   rules over a byte slice (QEMU's PSRAM, hal-sim's state file, tests).

pub mod flash;
pub mod password;
pub mod record;
