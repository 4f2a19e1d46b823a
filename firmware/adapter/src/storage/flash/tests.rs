//! Each rule of the flash, broken on purpose: the operation fails with its
//! error and the memory is unchanged.

use super::*;
use nor::{NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};

/// 4 pages of 16 bytes, words of 4 bytes.
type Flash<'a> = RuleFlash<'a, 4, 16>;

fn erased() -> Vec<u8> {
    vec![0xff; 64]
}

#[test]
fn erase_sets_whole_pages_to_ff() {
    let mut memory = vec![0u8; 64];
    let mut flash = Flash::new(&mut memory);
    flash.erase(16, 48).unwrap();
    assert_eq!(flash.erases(), 2, "two pages");
    assert_eq!(&flash.memory()[..16], &[0; 16], "the page before is untouched");
    assert_eq!(&flash.memory()[16..48], &[0xff; 32]);
    assert_eq!(&flash.memory()[48..], &[0; 16], "the page after is untouched");
    flash.erase(0, 0).unwrap();
    assert_eq!(flash.erases(), 2, "an empty erase erases nothing");
}

#[test]
fn erase_needs_page_boundaries() {
    let mut memory = vec![0u8; 64];
    let mut flash = Flash::new(&mut memory);
    for (from, to) in [(4, 16), (0, 20), (8, 24), (1, 17)] {
        assert_eq!(flash.erase(from, to), Err(FlashError::NotAligned), "{from}..{to}");
    }
    assert_eq!(flash.erase(4, 16).unwrap_err().kind(), NorFlashErrorKind::NotAligned);
    assert_eq!(flash.memory(), &[0; 64], "nothing erased");
    assert_eq!(flash.erases(), 0);
}

#[test]
fn erase_stays_inside() {
    let mut memory = vec![0u8; 64];
    let mut flash = Flash::new(&mut memory);
    for (from, to) in [(0, 80), (64, 80), (32, 16), (u32::MAX - 15, u32::MAX)] {
        assert_eq!(flash.erase(from, to), Err(FlashError::OutOfBounds), "{from}..{to}");
    }
    assert_eq!(flash.erase(0, 80).unwrap_err().kind(), NorFlashErrorKind::OutOfBounds);
    assert_eq!(flash.memory(), &[0; 64]);
}

#[test]
fn writes_only_clear_bits() {
    let mut memory = erased();
    let mut flash = Flash::new(&mut memory);
    flash.write(4, &[0x0f, 0xf0, 0x00, 0xff]).unwrap();
    assert_eq!(&flash.memory()[4..8], &[0x0f, 0xf0, 0x00, 0xff]);
    // Clearing more bits of the same word is legal (multiwrite).
    flash.write(4, &[0x0e, 0x70, 0x00, 0x7f]).unwrap();
    assert_eq!(&flash.memory()[4..8], &[0x0e, 0x70, 0x00, 0x7f]);
    // Setting any cleared bit is not, and the whole write is refused.
    let before = flash.memory().to_vec();
    assert_eq!(
        flash.write(0, &[0x00, 0x00, 0x00, 0x00, 0x0e, 0x70, 0x01, 0x7f]),
        Err(FlashError::SetsBit { offset: 6 })
    );
    assert_eq!(flash.write(4, &[0xff; 4]).unwrap_err().kind(), NorFlashErrorKind::Other);
    assert_eq!(flash.memory(), &before[..], "a refused write wrote nothing, not even its first word");
    assert_eq!(flash.writes(), 2);
    // An erase makes the word writable again.
    flash.erase(0, 16).unwrap();
    flash.write(4, &[0xa5; 4]).unwrap();
    assert_eq!(&flash.memory()[4..8], &[0xa5; 4]);
}

#[test]
fn writes_need_word_alignment() {
    let mut memory = erased();
    let mut flash = Flash::new(&mut memory);
    for (offset, len) in [(1, 4), (2, 4), (0, 3), (4, 5), (3, 1)] {
        assert_eq!(flash.write(offset, &vec![0; len]), Err(FlashError::NotAligned), "{offset}+{len}");
    }
    assert_eq!(flash.write(1, &[0; 4]).unwrap_err().kind(), NorFlashErrorKind::NotAligned);
    assert_eq!(flash.memory(), &erased()[..], "nothing written");
    flash.write(60, &[0; 4]).unwrap();
    flash.write(8, &[]).unwrap();
}

#[test]
fn writes_and_reads_stay_inside() {
    let mut memory = erased();
    let mut flash = Flash::new(&mut memory);
    assert_eq!(flash.write(64, &[0; 4]), Err(FlashError::OutOfBounds));
    assert_eq!(flash.write(60, &[0; 8]), Err(FlashError::OutOfBounds));
    assert_eq!(flash.write(u32::MAX - 3, &[0; 4]), Err(FlashError::OutOfBounds));
    assert_eq!(flash.memory(), &erased()[..]);
    let mut buf = [0u8; 8];
    assert_eq!(flash.read(60, &mut buf), Err(FlashError::OutOfBounds));
    assert_eq!(flash.read(u32::MAX, &mut buf[..1]), Err(FlashError::OutOfBounds));
    flash.read(61, &mut buf[..3]).unwrap();
    assert_eq!(buf[..3], [0xff; 3], "reads take any offset and length");
}

#[test]
fn a_tail_shorter_than_a_page_is_not_flash() {
    let mut memory = vec![0xffu8; 40];
    let mut flash = Flash::new(&mut memory);
    assert_eq!(ReadNorFlash::capacity(&flash), 32);
    assert_eq!(flash.write(32, &[0; 4]), Err(FlashError::OutOfBounds));
    assert_eq!(flash.erase(32, 48), Err(FlashError::OutOfBounds));
    assert_eq!(flash.read(36, &mut [0; 1]), Err(FlashError::OutOfBounds));
}

/// The async traits (a module of their own: their methods share the blocking ones' names).
mod asynchronous {
    use super::super::*;
    use super::{Flash, erased};
    use embassy_futures::block_on;
    use nor_async::{NorFlash as _, ReadNorFlash as _};

    #[test]
    fn follow_the_same_rules() {
        let mut memory = erased();
        let mut flash = Flash::new(&mut memory);
        block_on(async {
            flash.write(0, &[0x00; 4]).await.unwrap();
            assert_eq!(flash.write(0, &[0x01, 0, 0, 0]).await, Err(FlashError::SetsBit { offset: 0 }));
            assert_eq!(flash.write(2, &[0; 4]).await, Err(FlashError::NotAligned));
            assert_eq!(flash.erase(0, 8).await, Err(FlashError::NotAligned));
            assert_eq!(flash.erase(0, 128).await, Err(FlashError::OutOfBounds));
            let mut buf = [0u8; 4];
            flash.read(0, &mut buf).await.unwrap();
            assert_eq!(buf, [0; 4]);
            flash.erase(0, 64).await.unwrap();
            flash.read(0, &mut buf).await.unwrap();
            assert_eq!(buf, [0xff; 4]);
        });
        assert_eq!((flash.erases(), flash.writes()), (4, 1));
    }
}
