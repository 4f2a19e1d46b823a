//! The settings store: arbitrary bytes as a settings record and as the
//! flash image a board starts with.
//!
//! The input ([`StoreInput`]):
//!
//! ```text
//! | layout (1) | bytes |
//! ```
//!
//! `bytes` is decoded as a record, and laid into a range of two 4 KiB
//! pages as `layout` says ([`StoreInput::image`]), which a [`Store`] then
//! loads, saves into and loads again.
//!
//! What is checked:
//!
//! - The record decoder takes exactly the records a model written here
//!   from the format's description takes (std string handling, not the
//!   library's), and gives the same settings: every field named by a line
//!   has that line's value, every other field the factory's, and the whole
//!   validates. Anything else is rejected whole.
//! - A load never panics and always ends; it gives the factory settings or
//!   exactly what the settings record in the image decodes to (read with
//!   sequential-storage directly), `ok` exactly when it reports no error,
//!   and never settings that fail validation.
//! - After a save that succeeds, the next load gives the saved settings.

use adapter::settings::{Field, Settings};
use adapter::storage::flash::RuleFlash;
use adapter::storage::record::{self, Decoded, VERSION};
use adapter::storage::{LoadError, Loaded, PasswordHash, Store};
use embassy_futures::block_on;
use sequential_storage::cache::Cache;
use sequential_storage::map::{MapConfig, MapStorage};

/// The page size of the fuzzed store.
pub const PAGE: usize = 4096;
/// The store's range: two pages.
pub const RANGE: core::ops::Range<u32> = 0..(2 * PAGE) as u32;

/// Layout bit 0: the bytes go into the second page (else the first).
pub const SECOND_PAGE: u8 = 1 << 0;
/// Layout bit 1: the other page holds the bytes too (else it is erased).
pub const BOTH_PAGES: u8 = 1 << 1;
/// Layout bit 2: the bytes not given are 0x00 (else erased, 0xFF).
pub const ZERO_FILL: u8 = 1 << 2;

type Flash<'a> = RuleFlash<'a, 4, PAGE>;

/// The store target's input.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct StoreInput<'a> {
    pub layout: u8,
    pub bytes: &'a [u8],
}

impl<'a> StoreInput<'a> {
    pub fn parse(data: &'a [u8]) -> Self {
        match data.split_first() {
            Some((&layout, bytes)) => Self { layout, bytes },
            None => Self::default(),
        }
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        [&[self.layout], self.bytes].concat()
    }

    /// The flash image: `bytes` at the start of a page (at most a page of them).
    pub fn image(&self) -> Vec<u8> {
        let fill = if self.layout & ZERO_FILL != 0 { 0x00 } else { 0xff };
        let mut image = vec![0xff; 2 * PAGE];
        let bytes = &self.bytes[..self.bytes.len().min(PAGE)];
        let (first, second) = image.split_at_mut(PAGE);
        let (page, other) = if self.layout & SECOND_PAGE != 0 { (second, first) } else { (first, second) };
        page.fill(fill);
        page[..bytes.len()].copy_from_slice(bytes);
        if self.layout & BOTH_PAGES != 0 {
            other.copy_from_slice(page);
        }
        image
    }
}

/// The factory settings of the fuzzed device: not the defaults, so a field
/// taken from them shows.
pub fn factory() -> Settings {
    let mut s = Settings::DEFAULT;
    for (field, text) in [
        (Field::DeviceName, "factory"),
        (Field::NetworkAddress, "198.18.0.2/24"),
        (Field::ModbusUnitId, "1"),
        (Field::WatchdogTimeout, "1000"),
    ] {
        s.set(field, text).expect("the fuzz factory settings");
    }
    s
}

/// The settings a fuzz input saves: valid and unlike the factory's.
pub fn saved() -> Settings {
    let mut s = factory();
    s.set(Field::NetworkMode, "static").expect("static");
    s.set(Field::DeviceName, "saved-by-fuzz").expect("name");
    s.set(Field::ModbusAllowWrite, "10.0.0.0/8,192.168.1.7").expect("allow");
    s
}

/// Checks the record decoder alone against its model: the `record` target,
/// fast enough for tens of millions of runs (the `store` target does this
/// and a whole store's load and save per input).
pub fn record(data: &[u8]) {
    check_record(data, &factory());
}

/// Checks the record decoder, and the store over the image (see the module).
pub fn store(data: &[u8]) {
    let input = StoreInput::parse(data);
    let factory = factory();
    check_record(input.bytes, &factory);

    let image = input.image();
    let first = load(&mut image.clone(), &factory);
    check_load(&image, &first, &factory);

    let mut memory = image;
    let saved = saved();
    let result = {
        let mut store = Store::new(Flash::new(&mut memory), RANGE).expect("the range");
        block_on(store.load(&factory));
        block_on(store.save_settings(&saved))
    };
    if result.is_ok() {
        let again = load(&mut memory, &factory);
        assert_eq!(again.settings, saved, "a saved change did not load back ({:?})", again.error);
        assert!(!matches!(again.error, Some(LoadError::Settings(_) | LoadError::Unformatted)), "{:?}", again.error);
    }
}

fn load(memory: &mut [u8], factory: &Settings) -> Loaded {
    let mut store = Store::new(Flash::new(memory), RANGE).expect("the range");
    block_on(store.load(factory))
}

/// The load against the image's settings record, read with sequential-storage directly.
fn check_load(image: &[u8], loaded: &Loaded, factory: &Settings) {
    assert_eq!(loaded.status.ok, loaded.error.is_none(), "ok is no error: {:?}", loaded.error);
    loaded.settings.validate().expect("loaded settings validate");
    let mut memory = image.to_vec();
    let config = MapConfig::try_new(RANGE).expect("the range");
    let mut map = MapStorage::<u8, _, _>::new(Flash::new(&mut memory), config, Cache::new_uncached());
    let mut buffer = [0u8; 2048];
    let expected = match block_on(map.fetch_item::<&[u8]>(&mut buffer, &1)) {
        Ok(Some(record)) => match record::decode(record, factory) {
            Ok(decoded) => {
                assert_eq!(loaded.skipped, decoded.skipped, "skipped lines");
                Some(decoded.settings)
            }
            Err(e) => {
                assert_eq!(loaded.error, Some(LoadError::Settings(e)), "a rejected record is reported");
                None
            }
        },
        // No record, or none readable: only the factory settings will do.
        Ok(None) | Err(_) => None,
    };
    match expected {
        Some(settings) => assert_eq!(loaded.settings, settings, "not the image's record"),
        None => assert_eq!(loaded.settings, *factory, "settings from nowhere"),
    }
}

/// The decoder against the model: the same answer, the same settings.
fn check_record(bytes: &[u8], factory: &Settings) {
    let decoded = record::decode(bytes, factory);
    let model = model(bytes, factory);
    match (&decoded, &model) {
        (Ok(d), Some(m)) => assert_eq!(d, m, "decoded otherwise than the model"),
        (Err(_), None) => {}
        _ => panic!("decoder {decoded:?}, model {model:?} for {:?}", String::from_utf8_lossy(bytes)),
    }
    if let Ok(decoded) = decoded {
        // What is taken is saved again as it was.
        let mut out = [0u8; record::MAX_RECORD_LEN];
        let len = record::encode(&decoded.settings, &mut out).expect("a decoded record encodes");
        let again = record::decode(&out[..len], &Settings::DEFAULT).expect("an encoded record decodes");
        assert_eq!(again.settings, decoded.settings);
        assert_eq!(again.skipped, 0);
    }
}

/// The record format, read with std: version byte, then UTF-8 lines
/// `group.field=value\n` (words of a-z 0-9 _), no field twice, unknown
/// keys skipped; each value set on the factory settings; the whole
/// validated.
fn model(bytes: &[u8], factory: &Settings) -> Option<Decoded> {
    let (&version, text) = bytes.split_first()?;
    if version != VERSION {
        return None;
    }
    let text = std::str::from_utf8(text).ok()?;
    if !text.is_empty() && !text.ends_with('\n') {
        return None;
    }
    let word = |w: &str| !w.is_empty() && w.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
    let mut settings = *factory;
    let mut seen = std::collections::HashSet::new();
    let mut skipped = 0;
    for line in text.split_terminator('\n') {
        let (key, value) = line.split_once('=')?;
        let (group, name) = key.split_once('.')?;
        if !word(group) || !word(name) {
            return None;
        }
        let Some(field) = Field::ALL.iter().copied().find(|f| f.group() == group && f.name() == name) else {
            skipped += 1;
            continue;
        };
        if !seen.insert(field.key()) {
            return None;
        }
        settings.set(field, value).ok()?;
    }
    settings.validate().ok()?;
    Some(Decoded { settings, skipped })
}

/// The seeds of the store target: records and images of real saves.
/// The `record` target's seeds: records of the factory and saved settings,
/// a newer firmware's key, a misfit, another version.
pub fn record_seeds() -> Vec<Vec<u8>> {
    let mut records = Vec::new();
    let mut out = [0u8; record::MAX_RECORD_LEN];
    for settings in [Settings::DEFAULT, factory(), saved()] {
        let len = record::encode(&settings, &mut out).expect("encode");
        records.push(out[..len].to_vec());
    }
    records.push(b"\x01modbus.unit_id=9\nhttp.port=8080\n".to_vec());
    records.push(b"\x01network.mode=static\n".to_vec());
    records.push(b"\x02modbus.unit_id=9\n".to_vec());
    records
}

/// The `store` target's seeds: the records as [`StoreInput`]s, and images.
pub fn seeds() -> Vec<Vec<u8>> {
    let records = record_seeds();
    let mut seeds: Vec<Vec<u8>> = records.iter().map(|r| StoreInput { layout: 0, bytes: r }.to_bytes()).collect();

    // Images: the first page after one save, a save and a password, many saves.
    let hash = PasswordHash::new(b"fuzz password", [3; 16]).expect("password");
    let images: [&dyn Fn(&mut Store<Flash<'_>>); 3] = [
        &|store| block_on(store.save_settings(&saved())).expect("save"),
        &|store| {
            block_on(store.save_settings(&saved())).expect("save");
            block_on(store.save_password(&hash)).expect("save");
        },
        &|store| {
            for name in ["a", "b", "c", "d"] {
                let mut s = saved();
                s.set(Field::DeviceName, name).expect("name");
                block_on(store.save_settings(&s)).expect("save");
            }
        },
    ];
    for make in images {
        let mut memory = vec![0xff; 2 * PAGE];
        {
            let mut store = Store::new(Flash::new(&mut memory), RANGE).expect("the range");
            make(&mut store);
        }
        let used = PAGE - memory[..PAGE].iter().rev().take_while(|&&b| b == 0xff).count();
        let page = &memory[..used.next_multiple_of(4)];
        for layout in [0, SECOND_PAGE, BOTH_PAGES] {
            seeds.push(StoreInput { layout, bytes: page }.to_bytes());
        }
    }
    seeds.push(StoreInput { layout: ZERO_FILL, bytes: &[] }.to_bytes());
    seeds
}
