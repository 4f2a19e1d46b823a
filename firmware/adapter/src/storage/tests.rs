//! The store over a [`RuleFlash`]: fresh, garbage and corrupt ranges, every
//! record and its rule, and power cut at every step of a save.

use super::flash::{FlashError, RuleFlash};
use super::*;
use crate::settings::{Field, NetMode};
use embassy_futures::block_on;

const PAGE: usize = 4096;
const PAGES: usize = 2;
const RANGE: Range<u32> = 0..(PAGE * PAGES) as u32;
type Flash<'a> = RuleFlash<'a, 4, PAGE>;

fn erased() -> Vec<u8> {
    vec![0xff; PAGE * PAGES]
}

fn factory() -> Settings {
    let mut s = Settings::DEFAULT;
    s.set(Field::DeviceName, "factory").unwrap();
    s
}

/// Settings number `n`: each differs from the others and from the factory's.
fn settings(n: u32) -> Settings {
    let mut s = factory();
    s.set(Field::NetworkMode, "static").unwrap();
    s.set(Field::NetworkAddress, &format!("10.{}.{}.2/16", n % 200, n % 250)).unwrap();
    s.set(Field::ModbusIdleTimeout, &(n % 86_400).to_string()).unwrap();
    s.set(Field::ModbusAllowWrite, "10.0.0.0/8,192.168.0.0/16,172.16.0.0/12,198.18.0.0/15").unwrap();
    s.set(Field::DeviceName, &format!("saved-{n}")).unwrap();
    s.validate().unwrap();
    s
}

fn hash(password: &[u8]) -> PasswordHash {
    PasswordHash::new(password, [7; password::SALT_LEN]).unwrap()
}

fn load(memory: &mut [u8]) -> Loaded {
    let mut store = Store::new(Flash::new(memory), RANGE).unwrap();
    block_on(store.load(&factory()))
}

fn save(memory: &mut [u8], settings: &Settings) {
    let mut store = Store::new(Flash::new(memory), RANGE).unwrap();
    block_on(store.load(&factory()));
    block_on(store.save_settings(settings)).unwrap();
}

/// Writes `record` under `key` with sequential-storage itself, as another
/// firmware (or a bug) would have.
fn write_raw(memory: &mut [u8], key: u8, record: &[u8]) {
    let config = MapConfig::try_new(RANGE).unwrap();
    let mut map = MapStorage::<u8, _, NoCache>::new(Flash::new(memory), config, Cache::new_uncached());
    let mut buffer = [0u8; BUFFER_LEN];
    block_on(map.store_item(&mut buffer, &key, &record)).unwrap();
}

#[test]
fn a_fresh_range_loads_the_factory_settings_and_is_ok() {
    let mut memory = erased();
    let loaded = load(&mut memory);
    assert_eq!(loaded.settings, factory());
    assert!(matches!(loaded.password, Password::Unset));
    assert_eq!(loaded.error, None);
    assert_eq!(loaded.status, StorageStatus { ok: true, records: 0, erases: 0 });
    assert_eq!(memory, erased(), "a load of a fresh range writes nothing");
}

#[test]
fn saved_settings_and_password_load_back() {
    let mut memory = erased();
    {
        let mut store = Store::new(Flash::new(&mut memory), RANGE).unwrap();
        block_on(store.load(&factory()));
        block_on(store.save_settings(&settings(1))).unwrap();
        block_on(store.save_password(&hash(b"first password"))).unwrap();
        block_on(store.save_settings(&settings(2))).unwrap();
        assert_eq!(store.status(), StorageStatus { ok: true, records: 3, erases: 0 });
    }
    let loaded = load(&mut memory);
    assert_eq!(loaded.settings, settings(2));
    assert!(loaded.password.is_set());
    assert!(loaded.password.verify(b"first password") && !loaded.password.verify(b"second password"));
    assert_eq!((loaded.error, loaded.skipped), (None, 0));
    assert_eq!(loaded.status, StorageStatus { ok: true, records: 3, erases: 0 });
    // The password alone, the settings untouched.
    {
        let mut store = Store::new(Flash::new(&mut memory), RANGE).unwrap();
        block_on(store.save_password(&hash(b"second password"))).unwrap();
    }
    let loaded = load(&mut memory);
    assert_eq!(loaded.settings, settings(2));
    assert!(loaded.password.verify(b"second password") && !loaded.password.verify(b"first password"));
}

#[test]
fn a_change_is_a_new_record_and_pages_are_reused_in_turn() {
    let mut memory = erased();
    let mut store = Store::new(Flash::new(&mut memory), RANGE).unwrap();
    block_on(store.load(&factory()));
    block_on(store.save_password(&hash(b"kept all along"))).unwrap();
    let mut erases = 0;
    for n in 0..300 {
        let before = store.flash().memory().to_vec();
        block_on(store.save_settings(&settings(n))).unwrap();
        let status = store.status();
        assert!(status.ok);
        if status.erases == erases {
            // No page erased: the save only cleared bits (appended).
            let after = store.flash().memory();
            assert!(before.iter().zip(after).all(|(b, a)| a & !b == 0), "save {n} rewrote in place");
        }
        erases = status.erases;
    }
    assert!(erases >= 30, "300 saves of ~0.5 KiB went round 2 pages of 4 KiB: {erases} erases");
    assert_eq!(store.flash().erases(), erases, "the store counts every page erased");
    store.into_flash();
    let loaded = load(&mut memory);
    assert_eq!(loaded.settings, settings(299));
    assert!(loaded.password.verify(b"kept all along"), "reclaiming pages kept the password");
}

#[test]
fn factory_reset_erases_the_range() {
    let mut memory = erased();
    {
        let mut store = Store::new(Flash::new(&mut memory), RANGE).unwrap();
        block_on(store.save_settings(&settings(1))).unwrap();
        block_on(store.save_password(&hash(b"forgotten password"))).unwrap();
        block_on(store.factory_reset()).unwrap();
        assert_eq!(store.status(), StorageStatus { ok: true, records: 0, erases: PAGES as u32 });
    }
    assert_eq!(memory, erased());
    let loaded = load(&mut memory);
    assert_eq!(loaded.settings, factory());
    assert!(matches!(loaded.password, Password::Unset));
    assert!(loaded.status.ok);
}

#[test]
fn settings_that_break_a_rule_are_not_saved() {
    let mut memory = erased();
    save(&mut memory, &settings(1));
    let before = memory.clone();
    let mut store = Store::new(Flash::new(&mut memory), RANGE).unwrap();
    let mut bad = settings(1);
    bad.network.address = None; // static without an address
    assert_eq!(
        block_on(store.save_settings(&bad)),
        Err(StoreError::Record(RecordError::Inconsistent(Field::NetworkAddress)))
    );
    store.into_flash();
    assert_eq!(memory, before, "nothing written");
}

#[test]
fn garbage_loads_the_factory_settings_and_is_not_ok() {
    let mut images = vec![vec![0u8; PAGE * PAGES], vec![0x55; PAGE * PAGES]];
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    for _ in 0..32 {
        images.push(
            (0..PAGE * PAGES)
                .map(|_| {
                    seed ^= seed << 13;
                    seed ^= seed >> 7;
                    seed ^= seed << 17;
                    seed as u8
                })
                .collect(),
        );
    }
    // Half a range of garbage: the pages look used, the records do not.
    let mut half = erased();
    half[..PAGE].fill(0);
    images.push(half);
    for (i, mut memory) in images.into_iter().enumerate() {
        let loaded = load(&mut memory);
        assert!(!loaded.status.ok, "image {i}");
        assert_eq!(loaded.settings, factory());
        assert!(matches!(loaded.password, Password::Unset));
        assert!(!loaded.status.ok);
        assert!(matches!(loaded.error, Some(LoadError::Unformatted | LoadError::Storage(_))), "{:?}", loaded.error);
        // The next save makes the range the store's.
        save(&mut memory, &settings(3));
        let loaded = load(&mut memory);
        assert_eq!((loaded.settings, loaded.error, loaded.status.ok), (settings(3), None, true));
    }
}

#[test]
fn a_record_that_breaks_a_rule_is_rejected_whole() {
    let cases: &[(&[u8], LoadError)] = &[
        (b"\x01modbus.unit_id=9\nmodbus.port=0\n", LoadError::Settings(RecordError::Invalid(Field::ModbusPort))),
        (b"\x01network.mode=static\n", LoadError::Settings(RecordError::Inconsistent(Field::NetworkAddress))),
        (b"\x01modbus.unit_id=9\ngarbage\n", LoadError::Settings(RecordError::Malformed { line: 2 })),
        (b"\x02modbus.unit_id=9\n", LoadError::Settings(RecordError::Version(2))),
        (b"", LoadError::Settings(RecordError::Empty)),
    ];
    for (record, error) in cases {
        let mut memory = erased();
        {
            let mut store = Store::new(Flash::new(&mut memory), RANGE).unwrap();
            block_on(store.save_password(&hash(b"still good"))).unwrap();
        }
        write_raw(&mut memory, key::SETTINGS, record);
        let loaded = load(&mut memory);
        assert_eq!(loaded.settings, factory(), "{error:?}");
        assert_eq!(loaded.error, Some(*error));
        assert!(!loaded.status.ok);
        assert!(loaded.password.verify(b"still good"), "the other record stands");
        // Saving settings mends it.
        let mut store = Store::new(Flash::new(&mut memory), RANGE).unwrap();
        block_on(store.load(&factory()));
        block_on(store.save_settings(&settings(4))).unwrap();
        assert!(store.status().ok);
    }
}

#[test]
fn newer_keys_are_skipped_and_newer_records_kept() {
    let mut memory = erased();
    write_raw(&mut memory, key::SETTINGS, b"\x01modbus.unit_id=9\nhttp.port=8080\n");
    write_raw(&mut memory, 9, b"a newer firmware's record");
    let loaded = load(&mut memory);
    assert_eq!(loaded.settings.modbus.unit_id, Some(9));
    assert_eq!((loaded.skipped, loaded.error, loaded.status.records), (1, None, 2));
    let mut store = Store::new(Flash::new(&mut memory), RANGE).unwrap();
    for n in 0..40 {
        block_on(store.save_settings(&settings(n))).unwrap();
    }
    let config = MapConfig::try_new(RANGE).unwrap();
    let mut map = MapStorage::<u8, _, NoCache>::new(store.into_flash(), config, Cache::new_uncached());
    let mut buffer = [0u8; BUFFER_LEN];
    let kept = block_on(map.fetch_item::<&[u8]>(&mut buffer, &9)).unwrap();
    assert_eq!(kept, Some(&b"a newer firmware's record"[..]), "carried across page reclaims");
}

#[test]
fn an_unreadable_password_locks_rather_than_opens() {
    for record in [&b"\x02newer format"[..], b"\x01short", b""] {
        let mut memory = erased();
        save(&mut memory, &settings(1));
        write_raw(&mut memory, key::PASSWORD, record);
        let loaded = load(&mut memory);
        assert!(matches!(loaded.password, Password::Unreadable));
        assert!(loaded.password.is_set() && !loaded.password.verify(b""));
        assert_eq!(loaded.settings, settings(1));
        assert_eq!((loaded.error, loaded.status.ok), (Some(LoadError::Password), false));
    }
}

#[test]
fn the_range_must_be_pages_the_map_can_use() {
    let mut memory = erased();
    for range in [0..PAGE as u32, 0..0, 1..(2 * PAGE) as u32, 0..(2 * PAGE + 4) as u32, 0..(3 * PAGE) as u32] {
        assert_eq!(Store::new(Flash::new(&mut memory), range.clone()).unwrap_err(), StoreError::Range, "{range:?}");
    }
    let mut small = vec![0xffu8; 8 * 1024];
    let tiny_pages = RuleFlash::<4, 1024>::new(&mut small);
    assert_eq!(Store::new(tiny_pages, 0..4096).unwrap_err(), StoreError::Range);
}

/// A flash whose power fails after `budget` units of work: a written byte
/// is a unit, an erased page two (the first erases its first half). The
/// operation that runs out leaves its work half done, as a real cut does:
/// the words before the cut written, the word at the cut with only some
/// of its bits cleared, the page at the cut half erased. Every operation
/// after the cut fails.
struct PowerCut<'a> {
    flash: Flash<'a>,
    budget: Option<usize>,
    used: usize,
    cut: bool,
}

impl<'a> PowerCut<'a> {
    fn new(memory: &'a mut [u8]) -> Self {
        Self { flash: Flash::new(memory), budget: None, used: 0, cut: false }
    }

    /// Takes `units` of the budget; `Err(left)` when it runs out with `left` done.
    fn spend(&mut self, units: usize) -> Result<(), usize> {
        let left = self.budget.map_or(usize::MAX, |budget| budget.saturating_sub(self.used));
        if self.cut {
            return Err(0);
        }
        if units > left {
            self.cut = true;
            self.used += left;
            return Err(left);
        }
        self.used += units;
        Ok(())
    }
}

impl ErrorType for PowerCut<'_> {
    type Error = FlashError;
}

impl ReadNorFlash for PowerCut<'_> {
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        if self.cut {
            return Err(FlashError::OutOfBounds);
        }
        self.flash.read(offset, bytes).await
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl NorFlash for PowerCut<'_> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = PAGE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        let mut page = from;
        while page < to {
            match self.spend(2) {
                Ok(()) => self.flash.erase(page, page + PAGE as u32).await?,
                Err(left) => {
                    if left == 1 {
                        let start = page as usize;
                        self.flash.memory_mut()[start..start + PAGE / 2].fill(0xff);
                    }
                    return Err(FlashError::OutOfBounds);
                }
            }
            page += PAGE as u32;
        }
        Ok(())
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        match self.spend(bytes.len()) {
            Ok(()) => self.flash.write(offset, bytes).await,
            Err(done) => {
                // The whole words before the cut, then the word at the cut
                // with the bits of its first `done % 4` bytes and half of
                // the others cleared as asked: still only clearing bits.
                let whole = done / 4 * 4;
                self.flash.write(offset, &bytes[..whole]).await?;
                if let Some(word) = bytes.get(whole..whole + 4) {
                    let at = offset + whole as u32;
                    let mut old = [0u8; 4];
                    self.flash.read(at, &mut old).await?;
                    let torn: Vec<u8> = (0..4)
                        .map(|i| if i < done % 4 { old[i] & word[i] } else { old[i] & (word[i] | 0x5a) })
                        .collect();
                    self.flash.write(at, &torn).await?;
                }
                Err(FlashError::OutOfBounds)
            }
        }
    }
}

/// Runs `change` on a store over a copy of `image`, its power cut after
/// `budget` units; returns the memory after the cut and whether it came.
fn cut_at(
    image: &[u8],
    budget: Option<usize>,
    change: &dyn Fn(&mut Store<PowerCut<'_>>) -> Result<(), StoreError>,
) -> (Vec<u8>, usize, bool) {
    let mut memory = image.to_vec();
    let mut store = Store::new(PowerCut::new(&mut memory), RANGE).unwrap();
    block_on(store.load(&factory()));
    store.flash().budget = budget;
    let result = change(&mut store);
    let (used, cut) = (store.flash().used, store.flash().cut);
    assert_eq!(result.is_err(), cut, "a save fails exactly when the power is cut");
    store.into_flash();
    (memory, used, cut)
}

/// Cuts `change` at every unit of its work on `image`; after each cut the
/// next start loads the settings `check` allows, and the store takes a new
/// save.
fn every_cut(
    image: &[u8],
    change: &dyn Fn(&mut Store<PowerCut<'_>>) -> Result<(), StoreError>,
    check: &dyn Fn(&Loaded, usize),
) -> usize {
    let (_, total, cut) = cut_at(image, None, change);
    assert!(!cut);
    for budget in 0..total {
        let (mut memory, _, cut) = cut_at(image, Some(budget), change);
        assert!(cut, "budget {budget} of {total}");
        let loaded = load(&mut memory);
        check(&loaded, budget);
        save(&mut memory, &settings(999));
        let again = load(&mut memory);
        assert_eq!((again.settings, again.error), (settings(999), None), "after the cut at {budget}");
    }
    total
}

fn settings_old_or_new(old: Settings, new: Settings) -> impl Fn(&Loaded, usize) {
    move |loaded, budget| {
        assert!(
            loaded.settings == old || loaded.settings == new,
            "cut at {budget}: neither the old nor the new settings ({:?})",
            loaded.error
        );
        if loaded.settings == new || old != factory() {
            assert_eq!(loaded.error, None, "cut at {budget}");
        }
    }
}

#[test]
fn a_first_save_cut_anywhere_leaves_factory_or_new() {
    let new = settings(1);
    let total =
        every_cut(&erased(), &|store| block_on(store.save_settings(&new)), &settings_old_or_new(factory(), new));
    assert!(total > 400, "{total} units");
}

#[test]
fn a_save_cut_anywhere_leaves_old_or_new() {
    let mut image = erased();
    save(&mut image, &settings(1));
    let new = settings(2);
    every_cut(&image, &|store| block_on(store.save_settings(&new)), &settings_old_or_new(settings(1), new));
}

#[test]
fn a_save_that_reclaims_a_page_cut_anywhere_leaves_old_or_new() {
    // Save until the next save has to erase a page, with the password's
    // record in the page to reclaim.
    let mut image = erased();
    {
        let mut store = Store::new(Flash::new(&mut image), RANGE).unwrap();
        block_on(store.save_password(&hash(b"must survive"))).unwrap();
    }
    let mut n = 0;
    loop {
        let mut probe = image.clone();
        let mut store = Store::new(Flash::new(&mut probe), RANGE).unwrap();
        block_on(store.save_settings(&settings(n + 1))).unwrap();
        if store.status().erases > 0 {
            break;
        }
        store.into_flash();
        save(&mut image, &settings(n + 1));
        n += 1;
    }
    let (old, new) = (settings(n), settings(n + 1));
    let check = settings_old_or_new(old, new);
    let total = every_cut(&image, &|store| block_on(store.save_settings(&new)), &|loaded, budget| {
        check(loaded, budget);
        assert!(loaded.password.verify(b"must survive"), "cut at {budget}: the password was lost");
    });
    assert!(total > 900, "the save moved the records of a page and erased it: {total} units");
}

#[test]
fn a_password_save_cut_anywhere_leaves_old_or_new() {
    let mut image = erased();
    {
        let mut store = Store::new(Flash::new(&mut image), RANGE).unwrap();
        block_on(store.save_settings(&settings(1))).unwrap();
        block_on(store.save_password(&hash(b"old password"))).unwrap();
    }
    let new = hash(b"new password");
    every_cut(&image, &|store| block_on(store.save_password(&new)), &|loaded, budget| {
        assert_eq!(loaded.settings, settings(1), "cut at {budget}");
        assert!(loaded.password.verify(b"old password") || loaded.password.verify(b"new password"), "cut at {budget}");
        assert_eq!(loaded.error, None);
    });
}

#[test]
fn a_factory_reset_cut_anywhere_leaves_old_or_factory() {
    let mut image = erased();
    save(&mut image, &settings(1));
    every_cut(&image, &|store| block_on(store.factory_reset()), &|loaded, budget| {
        assert!(loaded.settings == settings(1) || loaded.settings == factory(), "cut at {budget}");
    });
}

#[test]
fn the_store_needs_no_multiwrite() {
    // The store takes any NorFlash; RuleFlash also offers multiwrite, which
    // the store never relies on (a flash with ECC cannot).
    fn multiwrite<F: embedded_storage_async::nor_flash::MultiwriteNorFlash>(_: &F) {}
    let mut memory = erased();
    multiwrite(&Flash::new(&mut memory));
    let _ = Store::new(PowerCut::new(&mut memory), RANGE).unwrap();
    assert_eq!(NetMode::Dhcp, Settings::DEFAULT.network.mode);
}
