//! The updater over flash with real rules (RuleFlash: erase to 0xFF, writes
//! only clear bits), and embassy-boot's own bootloader over the same bytes:
//! what is armed is what the bootloader swaps in, what is refused leaves
//! it booting the old image.

use ed25519_dalek::{Signer, SigningKey};
use embassy_boot::{BootLoader, BootLoaderConfig};
use embassy_futures::block_on;
use proptest::prelude::*;

use super::*;
use crate::storage::flash::RuleFlash;

const WORD: usize = 4;
const PAGE: usize = 4096;
type Flash<'a> = RuleFlash<'a, WORD, PAGE>;

/// ACTIVE: 4 pages; DFU one page more, as embassy-boot's swap needs.
const ACTIVE_LEN: usize = 4 * PAGE;
const DFU_LEN: usize = ACTIVE_LEN + PAGE;
const STATE_LEN: usize = PAGE;
const BOARD: &str = "mps2-an386";
/// A payload that is no multiple of a block or a word.
const PAYLOAD_LEN: usize = 5 * BLOCK_LEN + 123;

/// The three partitions' bytes, as a board's flash holds them.
struct Bench {
    active: Vec<u8>,
    dfu: Vec<u8>,
    state: Vec<u8>,
    aligned: [u8; MAX_STATE_WORD],
}

/// The image running before the update: a pattern no payload here has.
fn old_image() -> Vec<u8> {
    (0..ACTIVE_LEN).map(|i| (i % 251) as u8).collect()
}

impl Bench {
    fn new() -> Self {
        Self {
            active: old_image(),
            dfu: vec![0xff; DFU_LEN],
            state: vec![0xff; STATE_LEN],
            aligned: [0; MAX_STATE_WORD],
        }
    }

    /// The running image's updater, with `key` trusted.
    fn updater(&mut self, key: [u8; 32]) -> Updater<'_, Flash<'_>, Flash<'_>> {
        let config = Config { board: BOARD, max_len: ACTIVE_LEN as u32, public_key: key, check: image::verify };
        Updater::new(Flash::new(&mut self.dfu), Flash::new(&mut self.state), &mut self.aligned, config).unwrap()
    }

    /// A reset: embassy-boot's bootloader runs over the partitions (a swap
    /// or a revert when the state asks for one) and says the state it found.
    fn reset(&mut self) -> embassy_boot::State {
        let mut bootloader = BootLoader::new(BootLoaderConfig {
            active: Flash::new(&mut self.active),
            dfu: Flash::new(&mut self.dfu),
            state: Flash::new(&mut self.state),
        });
        let mut aligned = [0u8; 256];
        bootloader.prepare_boot(&mut aligned).unwrap()
    }

    /// Checks that nothing is armed: the state says so, and a reset boots
    /// the old image untouched.
    fn assert_nothing_armed(&mut self) {
        assert_eq!(block_on(self.updater(public_key()).boot_state()), Ok(BootState::Confirmed));
        assert_eq!(self.reset(), embassy_boot::State::Boot);
        assert!(self.active == old_image(), "ACTIVE changed");
    }
}

fn signing_key() -> SigningKey {
    SigningKey::from_bytes(&[0x42; 32])
}

fn public_key() -> [u8; 32] {
    signing_key().verifying_key().to_bytes()
}

fn payload(len: usize, seed: u8) -> Vec<u8> {
    (0..len).map(|i| (i as u8).wrapping_mul(7).wrapping_add(seed) ^ 0x5a).collect()
}

/// An update file: `payload` for `board`, version 0.2.0, signed with `key`.
fn image_for(board: &str, payload: &[u8], key: &SigningKey) -> Vec<u8> {
    let mut header = Header {
        board: Board::new(board).unwrap(),
        version: Version { major: 0, minor: 2, patch: 0 },
        payload_len: payload.len() as u32,
        signature: [0; image::SIGNATURE_LEN],
    };
    let mut digest = header.digest();
    digest.update(payload);
    header.signature = key.sign(&digest.finalize()).to_bytes();
    let mut file = header.emit().to_vec();
    file.extend_from_slice(payload);
    file
}

fn image(payload: &[u8]) -> Vec<u8> {
    image_for(BOARD, payload, &signing_key())
}

/// Uploads `file` in chunks of `chunk` bytes: the first error, or what
/// `finish` says.
async fn upload<D: NorFlash, S: NorFlash>(
    updater: &mut Updater<'_, D, S>,
    file: &[u8],
    chunk: usize,
) -> Result<Accepted, Error> {
    updater.begin().await?;
    for part in file.chunks(chunk) {
        updater.write(part).await?;
    }
    updater.finish().await
}

#[test]
fn a_good_image_is_armed_swapped_in_and_confirmed() {
    let mut bench = Bench::new();
    let payload = payload(PAYLOAD_LEN, 1);
    let file = image(&payload);
    {
        let mut updater = bench.updater(public_key());
        let accepted = block_on(upload(&mut updater, &file, 1000)).unwrap();
        assert_eq!(accepted, Accepted { version: Version { major: 0, minor: 2, patch: 0 }, len: PAYLOAD_LEN as u32 });
        assert_eq!(block_on(updater.boot_state()), Ok(BootState::Armed));
        assert_eq!(updater.armed(), Some(accepted));
        // Armed: no second upload, and confirming (nothing on trial) keeps it armed.
        assert_eq!(block_on(updater.begin()), Err(Error::Armed));
        assert_eq!(block_on(updater.confirm()), Ok(false));
    }
    // The reset: the bootloader swaps the payload into ACTIVE.
    assert_eq!(bench.reset(), embassy_boot::State::Swap);
    assert_eq!(&bench.active[..PAYLOAD_LEN], &payload[..]);
    // The new image, on trial, confirms itself; later resets keep it.
    {
        let mut updater = bench.updater(public_key());
        assert_eq!(block_on(updater.boot_state()), Ok(BootState::Trial));
        assert_eq!(block_on(updater.begin()), Err(Error::OnTrial));
        assert_eq!(block_on(updater.confirm()), Ok(true));
        assert_eq!(block_on(updater.boot_state()), Ok(BootState::Confirmed));
        assert_eq!(block_on(updater.confirm()), Ok(false));
    }
    assert_eq!(bench.reset(), embassy_boot::State::Boot);
    assert_eq!(&bench.active[..PAYLOAD_LEN], &payload[..]);
}

#[test]
fn an_image_that_never_confirms_is_rolled_back() {
    let mut bench = Bench::new();
    let payload = payload(PAYLOAD_LEN, 2);
    block_on(upload(&mut bench.updater(public_key()), &image(&payload), 4096)).unwrap();
    assert_eq!(bench.reset(), embassy_boot::State::Swap);
    assert_eq!(&bench.active[..PAYLOAD_LEN], &payload[..]);
    // No confirmation: the next reset reverts.
    assert_eq!(bench.reset(), embassy_boot::State::Swap);
    assert!(bench.active == old_image(), "the old image is not back");
    let mut updater = bench.updater(public_key());
    assert_eq!(block_on(updater.boot_state()), Ok(BootState::RolledBack));
    // The old image may take an update again.
    assert_eq!(block_on(updater.begin()), Ok(()));
}

#[test]
fn a_bad_signature_is_refused_and_nothing_is_armed() {
    let mut bench = Bench::new();
    let mut file = image(&payload(PAYLOAD_LEN, 3));
    let last = file.len() - 1;
    file[last] ^= 0x01;
    let result = block_on(upload(&mut bench.updater(public_key()), &file, 777));
    assert_eq!(result, Err(Error::Signature(SignatureError::Mismatch)));
    assert_eq!(result.unwrap_err().kind(), ErrorKind::Image);
    bench.assert_nothing_armed();
}

#[test]
fn an_image_signed_with_another_key_is_refused() {
    let mut bench = Bench::new();
    let file = image_for(BOARD, &payload(PAYLOAD_LEN, 4), &SigningKey::from_bytes(&[9; 32]));
    let result = block_on(upload(&mut bench.updater(public_key()), &file, 512));
    assert_eq!(result, Err(Error::Signature(SignatureError::Mismatch)));
    bench.assert_nothing_armed();
}

/// Refusals the header decides: before anything is written or erased.
fn assert_refused_before_writing(file: &[u8], expected: Error) {
    let mut bench = Bench::new();
    {
        let mut dfu = Flash::new(&mut bench.dfu);
        let config =
            Config { board: BOARD, max_len: ACTIVE_LEN as u32, public_key: public_key(), check: image::verify };
        {
            let mut updater = Updater::new(&mut dfu, Flash::new(&mut bench.state), &mut bench.aligned, config).unwrap();
            assert_eq!(block_on(upload(&mut updater, file, 100)), Err(expected));
        }
        assert_eq!((dfu.erases(), dfu.writes()), (0, 0), "DFU touched");
    }
    bench.assert_nothing_armed();
}

#[test]
fn an_image_for_another_board_is_refused_before_writing() {
    let file = image_for("nucleo-f429zi", &payload(PAYLOAD_LEN, 5), &signing_key());
    assert_refused_before_writing(&file, Error::WrongBoard(Board::new("nucleo-f429zi").unwrap()));
}

#[test]
fn an_image_larger_than_active_is_refused_before_writing() {
    let file = image(&payload(ACTIVE_LEN + 1, 6));
    assert_refused_before_writing(&file, Error::TooLarge { len: ACTIVE_LEN as u32 + 1, max: ACTIVE_LEN as u32 });
    // ACTIVE's size exactly fits.
    let mut bench = Bench::new();
    let payload = payload(ACTIVE_LEN, 7);
    block_on(upload(&mut bench.updater(public_key()), &image(&payload), 4000)).unwrap();
    assert_eq!(bench.reset(), embassy_boot::State::Swap);
    assert!(bench.active == payload);
}

#[test]
fn garbage_is_refused_before_writing() {
    assert_refused_before_writing(&[0x3c; 3000], Error::Format(FormatError::Magic));
    let mut file = image(&payload(100, 8));
    file[8] = 1; // format version 1: a file whose digest is SHA-512
    assert_refused_before_writing(&file, Error::Format(FormatError::FormatVersion(1)));
}

#[test]
fn a_cut_off_upload_is_refused() {
    let file = image(&payload(PAYLOAD_LEN, 9));
    for cut in [0, 1, HEADER_LEN - 1, HEADER_LEN, HEADER_LEN + 1, HEADER_LEN + BLOCK_LEN, file.len() - 1] {
        let mut bench = Bench::new();
        let result = block_on(upload(&mut bench.updater(public_key()), &file[..cut], 300));
        let expected = if cut < HEADER_LEN { HEADER_LEN } else { file.len() } as u32;
        assert_eq!(result, Err(Error::CutOff { received: cut as u32, expected }), "cut at {cut}");
        bench.assert_nothing_armed();
    }
}

#[test]
fn bytes_past_the_announced_length_are_refused() {
    let mut bench = Bench::new();
    let mut file = image(&payload(PAYLOAD_LEN, 10));
    file.push(0);
    {
        let mut updater = bench.updater(public_key());
        assert_eq!(block_on(upload(&mut updater, &file, 64)), Err(Error::TooLong));
        // The error stays until the next begin.
        assert_eq!(block_on(updater.write(&[1])), Err(Error::TooLong));
        assert_eq!(block_on(updater.finish()), Err(Error::TooLong));
        assert_eq!(updater.progress(), None);
    }
    bench.assert_nothing_armed();
}

#[test]
fn every_chunk_size_gives_the_same_image() {
    let payload = payload(PAYLOAD_LEN, 11);
    let file = image(&payload);
    for chunk in [1, 3, 4, 127, 128, 129, 511, 512, 513, 4096, file.len()] {
        let mut bench = Bench::new();
        block_on(upload(&mut bench.updater(public_key()), &file, chunk)).unwrap();
        assert_eq!(&bench.dfu[..PAYLOAD_LEN], &payload[..], "chunks of {chunk}");
        // The tail of the last word is erased flash.
        assert!(bench.dfu[PAYLOAD_LEN..PAYLOAD_LEN.next_multiple_of(WORD)].iter().all(|&b| b == 0xff));
    }
}

/// A failed upload leaves DFU half written; the next one must erase what
/// it writes over again (embassy-boot's write_firmware would not).
#[test]
fn an_upload_after_a_failed_one_is_accepted() {
    let mut bench = Bench::new();
    let first = payload(PAYLOAD_LEN, 12);
    let second = payload(PAYLOAD_LEN - 600, 13);
    {
        let mut updater = bench.updater(public_key());
        let mut bad = image(&first);
        bad[HEADER_LEN] ^= 0xff;
        assert!(block_on(upload(&mut updater, &bad, 512)).is_err());
        // Cut off after the first blocks were written.
        let cut = image(&first);
        assert!(block_on(upload(&mut updater, &cut[..HEADER_LEN + 2 * BLOCK_LEN + 5], 512)).is_err());
        block_on(upload(&mut updater, &image(&second), 512)).unwrap();
    }
    assert_eq!(bench.reset(), embassy_boot::State::Swap);
    assert_eq!(&bench.active[..second.len()], &second[..]);
}

#[test]
fn write_and_finish_need_begin() {
    let mut bench = Bench::new();
    let mut updater = bench.updater(public_key());
    assert_eq!(block_on(updater.write(&[1, 2, 3])), Err(Error::NotStarted));
    assert_eq!(block_on(updater.finish()), Err(Error::NotStarted));
    assert_eq!(Error::NotStarted.kind(), ErrorKind::State);
    // abort drops an upload.
    block_on(updater.begin()).unwrap();
    block_on(updater.write(&[0; 10])).unwrap();
    updater.abort();
    assert_eq!(block_on(updater.write(&[0; 10])), Err(Error::NotStarted));
}

#[test]
fn progress_counts_the_file_s_bytes() {
    let mut bench = Bench::new();
    let file = image(&payload(PAYLOAD_LEN, 14));
    let total = file.len() as u32;
    let mut updater = bench.updater(public_key());
    assert_eq!(updater.progress(), None);
    block_on(updater.begin()).unwrap();
    assert_eq!(block_on(updater.write(&file[..100])), Ok(Progress { received: 100, total: None }));
    assert_eq!(block_on(updater.write(&file[100..1000])), Ok(Progress { received: 1000, total: Some(total) }));
    assert_eq!(block_on(updater.write(&file[1000..])), Ok(Progress { received: total, total: Some(total) }));
    // An empty chunk changes nothing.
    assert_eq!(block_on(updater.write(&[])), Ok(Progress { received: total, total: Some(total) }));
    block_on(updater.finish()).unwrap();
    assert_eq!(updater.progress(), None);
}

#[test]
fn partitions_that_do_not_fit_are_a_config_error() {
    let mut bench = Bench::new();
    let key = public_key();
    let mut short = [0u8; WORD - 1];
    let good = Config { board: BOARD, max_len: ACTIVE_LEN as u32, public_key: key, check: image::verify };
    let cases = [(good, &mut short[..]), (Config { board: "MPS2", ..good }, &mut bench.aligned[..])];
    for (config, aligned) in cases {
        let updater = Updater::new(Flash::new(&mut bench.dfu), Flash::new(&mut bench.state), aligned, config);
        assert_eq!(updater.err(), Some(Error::Config));
    }
    let too_large = Config { max_len: DFU_LEN as u32 + 1, ..good };
    let updater = Updater::new(Flash::new(&mut bench.dfu), Flash::new(&mut bench.state), &mut bench.aligned, too_large);
    assert_eq!(updater.err(), Some(Error::Config));
}

/// The key the firmware builds in by default is the committed development
/// key: an image signed with `keys/update-dev.key` is accepted by
/// `Config::new`. (Built with `UPDATE_PUBLIC_KEY` naming another key, only
/// `DEVELOPMENT_KEY` is checked.)
#[test]
fn the_built_in_key_is_the_development_key() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../keys/update-dev.key");
    let text = std::fs::read_to_string(path).unwrap();
    let hex: String = text.lines().filter(|line| !line.starts_with('#')).collect::<String>();
    let seed: Vec<u8> = (0..32).map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap()).collect();
    let key = SigningKey::from_bytes(&seed.try_into().unwrap());
    assert_eq!(DEVELOPMENT_KEY, key.verifying_key().to_bytes() == PUBLIC_KEY);
    if !DEVELOPMENT_KEY {
        return;
    }

    let mut bench = Bench::new();
    let file = image_for(BOARD, &payload(1000, 15), &key);
    let config = Config::new(BOARD, ACTIVE_LEN as u32, image::verify);
    let mut updater =
        Updater::new(Flash::new(&mut bench.dfu), Flash::new(&mut bench.state), &mut bench.aligned, config).unwrap();
    assert!(block_on(upload(&mut updater, &file, 512)).is_ok());
}

/// The boards' images check signatures in their bootloader: one that
/// serves no check leaves them refusing every upload, as the device's
/// fault, with nothing armed.
#[test]
fn without_a_check_every_upload_is_refused_and_nothing_armed() {
    fn unavailable(
        _: &[u8; image::PUBLIC_KEY_LEN],
        _: &[u8; image::DIGEST_LEN],
        _: &[u8; image::SIGNATURE_LEN],
    ) -> Result<(), SignatureError> {
        Err(SignatureError::Unavailable)
    }
    let mut bench = Bench::new();
    let file = image_for(BOARD, &payload(3000, 9), &signing_key());
    let config = Config { board: BOARD, max_len: ACTIVE_LEN as u32, public_key: public_key(), check: unavailable };
    let refused = {
        let mut updater =
            Updater::new(Flash::new(&mut bench.dfu), Flash::new(&mut bench.state), &mut bench.aligned, config).unwrap();
        block_on(upload(&mut updater, &file, 512)).unwrap_err()
    };
    assert_eq!(refused, Error::Signature(SignatureError::Unavailable));
    assert_eq!(refused.kind(), ErrorKind::Device);
    assert_eq!(refused.to_string(), "the signature cannot be checked: the bootloader offers no signature check");
    bench.assert_nothing_armed();
}

#[test]
fn errors_read_as_sentences() {
    let cut = Error::CutOff { received: 100, expected: 5000 };
    assert_eq!(cut.to_string(), "the upload was cut off: 100 of 5000 bytes");
    let board = Error::WrongBoard(Board::new("nucleo-f429zi").unwrap());
    assert_eq!(board.to_string(), "the image is for the board nucleo-f429zi");
    assert_eq!(Error::Flash(NorFlashErrorKind::Other).kind(), ErrorKind::Device);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Any bytes in any chunks: no panic, and nothing armed.
    #[test]
    fn arbitrary_uploads_are_never_armed(
        bytes in proptest::collection::vec(any::<u8>(), 0..3000),
        chunk in 1usize..700,
        magic in any::<bool>(),
    ) {
        let mut bytes = bytes;
        if magic && bytes.len() >= 8 {
            bytes[..8].copy_from_slice(&image::MAGIC);
        }
        let mut bench = Bench::new();
        let result = block_on(upload(&mut bench.updater(public_key()), &bytes, chunk));
        prop_assert!(result.is_err());
        bench.assert_nothing_armed();
    }

    /// A good image with one byte changed anywhere is never armed.
    #[test]
    fn a_changed_byte_anywhere_is_never_armed(at in 0..HEADER_LEN + 700, flip in 1u8..=255, chunk in 1usize..600) {
        let mut file = image(&payload(700, 16));
        file[at] ^= flip;
        let mut bench = Bench::new();
        prop_assert!(block_on(upload(&mut bench.updater(public_key()), &file, chunk)).is_err());
        bench.assert_nothing_armed();
    }
}

#[test]
fn an_image_record_round_trips_and_nothing_else_reads_as_one() {
    let version = crate::io::Version { major: 1, minor: 20, patch: 300 };
    let record = image_info(version);
    assert_eq!(parse_image_info(&record), Some(version));
    assert_eq!(parse_image_info(&[0xff; IMAGE_INFO_LEN]), None, "erased flash");
    assert_eq!(parse_image_info(&record[..IMAGE_INFO_LEN - 1]), None, "too short");
    for i in 0..IMAGE_INFO_LEN {
        let mut changed = record;
        changed[i] ^= 0x01;
        // The version's bytes make another version; the magic's and the zeros', no record.
        assert_eq!(parse_image_info(&changed).is_some(), (8..14).contains(&i), "byte {i} changed");
    }
}

/// Where the record is in the test images: past a pretend vector table.
const LAYOUT: ImageLayout = ImageLayout { info_offset: 0x40, page: PAGE as u32 };

/// A payload of `len` bytes carrying the record of `version`.
fn payload_of(version: crate::io::Version, len: usize, seed: u8) -> Vec<u8> {
    let mut payload = payload(len, seed);
    let at = LAYOUT.info_offset as usize;
    payload[at..at + IMAGE_INFO_LEN].copy_from_slice(&image_info(version));
    payload
}

#[test]
fn the_other_image_is_the_one_a_swap_replaced_or_a_rollback_rejected() {
    let old = crate::io::Version { major: 0, minor: 1, patch: 0 };
    let new = crate::io::Version { major: 0, minor: 2, patch: 0 };
    let mut bench = Bench::new();
    bench.active = payload_of(old, ACTIVE_LEN, 9);
    assert_eq!(block_on(bench.updater(public_key()).other_image(LAYOUT)), Ok(None), "never swapped: DFU is empty");
    let file = image(&payload_of(new, PAYLOAD_LEN, 1));
    {
        let mut updater = bench.updater(public_key());
        block_on(upload(&mut updater, &file, 1000)).unwrap();
        assert_eq!(block_on(updater.other_image(LAYOUT)), Ok(None), "armed: DFU holds the new image");
    }
    assert_eq!(bench.reset(), embassy_boot::State::Swap);
    {
        let mut updater = bench.updater(public_key());
        assert_eq!(block_on(updater.boot_state()), Ok(BootState::Trial));
        assert_eq!(block_on(updater.other_image(LAYOUT)), Ok(Some(old)), "on trial: the image it replaced");
    }
    // Not confirmed: the next reset rolls back, and the other image is the rejected one.
    assert_eq!(bench.reset(), embassy_boot::State::Swap);
    {
        let mut updater = bench.updater(public_key());
        assert_eq!(block_on(updater.boot_state()), Ok(BootState::RolledBack));
        assert_eq!(block_on(updater.other_image(LAYOUT)), Ok(Some(new)), "rolled back: the rejected image");
    }
    // Uploaded again, swapped in and confirmed: the old image is the other one.
    {
        let mut updater = bench.updater(public_key());
        block_on(upload(&mut updater, &file, 1000)).unwrap();
    }
    assert_eq!(bench.reset(), embassy_boot::State::Swap);
    let mut updater = bench.updater(public_key());
    assert_eq!(block_on(updater.confirm()), Ok(true));
    assert_eq!(block_on(updater.other_image(LAYOUT)), Ok(Some(old)), "confirmed: the image it replaced");
}

#[test]
fn the_boot_states_have_the_names_the_api_uses() {
    let names = [BootState::Confirmed, BootState::Trial, BootState::Armed, BootState::RolledBack, BootState::DfuDetach]
        .map(BootState::as_str);
    assert_eq!(names, ["confirmed", "trial", "armed", "rolled_back", "dfu_detach"]);
}
