//! Where hal-sim keeps the settings it saves: a NOR flash with real flash
//! rules ([`RuleFlash`]) over a state file (`--state FILE`), or over memory
//! when there is none (the settings then last until hal-sim exits).
//!
//! The file is mapped `MAP_SHARED`: every write of the flash is a store
//! into the kernel's page cache of the file, there at once, with no buffer
//! of hal-sim's own in between. A kill at any instant (SIGKILL, a crash)
//! leaves in the file exactly the writes made before it, as a power cut
//! leaves a board's flash; only a crash of the machine itself can lose
//! more, which hal-sim does not simulate.
//!
//! A missing file is made whole first (a temporary file of
//! [`STATE_LEN`] bytes of `0xFF`, renamed into place), so a kill while
//! making it never leaves a short one. A file of another size is refused:
//! it is not a state file of this hal-sim. The file is locked (`flock`)
//! while hal-sim runs, so a second hal-sim cannot share it.

use std::fmt;
use std::fs::{File, OpenOptions};
use std::io::{self, Write as _};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};

use adapter::storage::flash::{FlashError, RuleFlash};
use embassy_time::{Duration, Timer};
use embedded_storage_async::nor_flash as nor_async;

/// The flash's write unit, in bytes (the STM32F4's word).
pub const WRITE_LEN: usize = 4;
/// The flash's erase unit (a page), in bytes: the store's minimum.
pub const PAGE_LEN: usize = 4096;
/// Pages of the state file.
pub const PAGES: usize = 16;
/// The state file's size: 64 KiB, all of it the settings store's range.
pub const STATE_LEN: usize = PAGES * PAGE_LEN;

/// The flash rules over the state file, without the flash's timing.
pub type RawFlash = RuleFlash<'static, WRITE_LEN, PAGE_LEN>;

/// How long programming one word takes (the STM32F4 takes about 16 µs).
pub const WORD_PROGRAM_TIME: Duration = Duration::from_micros(16);
/// How long erasing one page takes (a 16 KiB STM32F4 sector takes about
/// 250 ms; a 4 KiB page is taken as a quarter).
pub const PAGE_ERASE_TIME: Duration = Duration::from_millis(60);

/// The settings flash hal-sim gives the store: the flash rules, and the
/// flash's time. Each write and erase first waits as long as the real one
/// takes (letting the executor run meanwhile), then lands in the file, so a
/// process killed during a save is cut between two flash operations, as a
/// board losing power mid-save would be (tearing inside one operation is the
/// storage unit tests' part).
#[derive(Debug)]
pub struct Flash {
    raw: RawFlash,
    timed: bool,
}

impl Flash {
    /// The flash over the rules, untimed until [`Flash::start_timing`].
    pub fn new(raw: RawFlash) -> Self {
        Self { raw, timed: false }
    }

    /// From now on writes and erases take their time (waits on embassy-time:
    /// only inside the executor, so not for the load at start-up).
    pub fn start_timing(&mut self) {
        self.timed = true;
    }

    async fn take(&self, time: Duration) {
        if self.timed {
            Timer::after(time).await;
        }
    }
}

impl nor_async::ErrorType for Flash {
    type Error = FlashError;
}

impl nor_async::ReadNorFlash for Flash {
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        nor_async::ReadNorFlash::read(&mut self.raw, offset, bytes).await
    }

    fn capacity(&self) -> usize {
        self.raw.capacity()
    }
}

impl nor_async::NorFlash for Flash {
    const WRITE_SIZE: usize = WRITE_LEN;
    const ERASE_SIZE: usize = PAGE_LEN;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        let pages = to.saturating_sub(from) / PAGE_LEN as u32;
        self.take(PAGE_ERASE_TIME * pages).await;
        nor_async::NorFlash::erase(&mut self.raw, from, to).await
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let words = u32::try_from(bytes.len() / WRITE_LEN).unwrap_or(u32::MAX);
        self.take(WORD_PROGRAM_TIME * words).await;
        nor_async::NorFlash::write(&mut self.raw, offset, bytes).await
    }
}

/// The store's range in the flash: all of it.
pub const RANGE: core::ops::Range<u32> = 0..STATE_LEN as u32;

/// Why the state file cannot be used.
#[derive(Debug)]
pub enum StateError {
    /// The file is there with another size: not a state file (a usage error).
    Size { path: PathBuf, len: u64 },
    /// Another program holds the file's lock (another hal-sim).
    Busy { path: PathBuf },
    /// The file cannot be made, opened or mapped.
    Io { path: PathBuf, error: io::Error },
}

impl StateError {
    /// Whether the command line is at fault (exit status 2), not the machine.
    pub fn is_usage(&self) -> bool {
        matches!(self, Self::Size { .. })
    }
}

impl fmt::Display for StateError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Size { path, len } => write!(
                f,
                "`--state {}` is {len} bytes, not {STATE_LEN}: not a hal-sim state file \
                 (give a new path, or delete this one to start from the factory settings)",
                path.display()
            ),
            Self::Busy { path } => {
                write!(f, "the state file {} is in use by another program (another hal-sim?)", path.display())
            }
            Self::Io { path, error } => write!(f, "cannot use the state file {}: {error}", path.display()),
        }
    }
}

impl std::error::Error for StateError {}

/// The flash over the state file at `path`, made (erased) when missing.
/// The mapping lives as long as the process (or until it re-executes
/// itself for a reboot, which unmaps it).
pub fn open(path: &Path) -> Result<Flash, StateError> {
    let io = |error| StateError::Io { path: path.to_owned(), error };
    if !path.exists() {
        create(path).map_err(io)?;
    }
    // std opens with O_CLOEXEC: a reboot's exec closes it (and drops the lock).
    let file = OpenOptions::new().read(true).write(true).open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    if len != STATE_LEN as u64 {
        return Err(StateError::Size { path: path.to_owned(), len });
    }
    // SAFETY: flock takes no pointers.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
        let error = io::Error::last_os_error();
        return Err(match error.raw_os_error() {
            Some(libc::EWOULDBLOCK) => StateError::Busy { path: path.to_owned() },
            _ => io(error),
        });
    }
    let memory = map(&file).map_err(io)?;
    // The lock lasts as long as the descriptor: keep it open for good.
    std::mem::forget(file);
    Ok(Flash::new(RawFlash::new(memory)))
}

/// The flash over memory, erased: the settings last until hal-sim exits.
pub fn in_memory() -> Flash {
    Flash::new(RawFlash::new(Box::leak(vec![0xff; STATE_LEN].into_boxed_slice())))
}

/// Makes `path` whole and erased: a temporary file beside it, renamed in.
fn create(path: &Path) -> io::Result<()> {
    let mut temporary = path.as_os_str().to_owned();
    temporary.push(format!(".new-{}", std::process::id()));
    let temporary = PathBuf::from(temporary);
    let mut file = File::create(&temporary)?;
    let written = file.write_all(&[0xff; STATE_LEN]).and_then(|()| file.sync_all());
    if let Err(e) = written.and_then(|()| std::fs::rename(&temporary, path)) {
        let _ = std::fs::remove_file(&temporary);
        return Err(e);
    }
    Ok(())
}

/// Maps the whole of `file` (of [`STATE_LEN`] bytes) shared, read and write.
fn map(file: &File) -> io::Result<&'static mut [u8]> {
    // SAFETY: a new mapping of STATE_LEN bytes of an open file; no address
    // is given, so it overlaps nothing of ours.
    let address = unsafe {
        libc::mmap(
            std::ptr::null_mut(),
            STATE_LEN,
            libc::PROT_READ | libc::PROT_WRITE,
            libc::MAP_SHARED,
            file.as_raw_fd(),
            0,
        )
    };
    if address == libc::MAP_FAILED {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: the mapping is STATE_LEN bytes, readable and writable, and is
    // never unmapped: it lives as long as the process. Nothing else in this
    // process refers to it. The file is locked against another hal-sim; a
    // program that ignores the lock and changes the file under us changes
    // the flash's bytes (as a bad flash would), and one that truncates it
    // kills hal-sim with SIGBUS, which is what it asked for.
    Ok(unsafe { std::slice::from_raw_parts_mut(address.cast::<u8>(), STATE_LEN) })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::panic, reason = "a failed step is a failed test")]
mod tests {
    use super::*;

    fn temporary(name: &str) -> PathBuf {
        let path = std::env::temp_dir().join(format!("hal-sim-state-test-{}-{name}", std::process::id()));
        let _ = std::fs::remove_file(&path);
        path
    }

    #[test]
    fn a_missing_file_is_made_erased_and_writes_land_in_it_at_once() {
        let path = temporary("fresh");
        let mut flash = open(&path).unwrap();
        assert_eq!(nor_async::ReadNorFlash::capacity(&flash), STATE_LEN);
        assert!(std::fs::read(&path).unwrap().iter().all(|&b| b == 0xff));
        embassy_futures::block_on(nor_async::NorFlash::write(&mut flash, 8, &[1, 2, 3, 4])).unwrap();
        // No flush, no drop: the bytes are in the file already.
        assert_eq!(std::fs::read(&path).unwrap().get(8..12), Some(&[1, 2, 3, 4][..]));
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn a_file_of_another_size_is_refused() {
        let path = temporary("short");
        std::fs::write(&path, [0xff; 100]).unwrap();
        let error = open(&path).unwrap_err();
        assert!(error.is_usage(), "{error}");
        assert!(error.to_string().contains("is 100 bytes, not 65536"), "{error}");
        let _ = std::fs::remove_file(&path);
    }
}
