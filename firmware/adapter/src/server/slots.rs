//! Session slots: who is connected, how long each has been idle, and the
//! eviction of the idlest session when a new client needs room
//! (Implementation Guide V1.0b, 4.2.1, connection management).

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::Instant;

use super::{Access, Rights, SLOT_COUNT};

/// Which slot (and listener task) a session runs in: `0..SLOT_COUNT`.
pub type SlotId = usize;

/// An open session: its last request, its client's address and what the
/// client may do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Entry {
    last: Instant,
    peer: [u8; 4],
    rights: Rights,
}

/// An open session as [`Slots::sessions`] reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Session {
    /// Its client's IPv4 address.
    pub peer: [u8; 4],
    /// When its last request (or its connection) came.
    pub last: Instant,
    /// What its client may do.
    pub rights: Rights,
}

/// One entry per socket while a session is open.
pub struct Slots {
    active: Mutex<CriticalSectionRawMutex, RefCell<[Option<Entry>; SLOT_COUNT]>>,
    evict: [Signal<CriticalSectionRawMutex, ()>; SLOT_COUNT],
}

impl core::fmt::Debug for Slots {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Slots").field("open", &self.open_count()).finish()
    }
}

impl Default for Slots {
    fn default() -> Self {
        Self::new()
    }
}

impl Slots {
    pub const fn new() -> Self {
        Self { active: Mutex::new(RefCell::new([None; SLOT_COUNT])), evict: [const { Signal::new() }; SLOT_COUNT] }
    }

    /// Opens slot `id` for a new session from `peer` with `rights`. If that
    /// makes more than `max` sessions, the one idle the longest is told to
    /// close; its id is returned.
    pub fn open(&self, id: SlotId, max: usize, now: Instant, peer: [u8; 4], rights: Rights) -> Option<SlotId> {
        if let Some(signal) = self.evict.get(id) {
            signal.reset();
        }
        let victim = self.active.lock(|active| {
            let mut active = active.borrow_mut();
            let slot = active.get_mut(id)?;
            *slot = Some(Entry { last: now, peer, rights });
            let open = active.iter().filter(|s| s.is_some()).count();
            if open <= max {
                return None;
            }
            let idlest = active
                .iter()
                .enumerate()
                .filter(|&(other, _)| other != id)
                .filter_map(|(other, entry)| entry.map(|entry| (entry.last, other)))
                .min()?;
            Some(idlest.1)
        });
        if let Some(signal) = victim.and_then(|v| self.evict.get(v)) {
            signal.signal(());
        }
        victim
    }

    /// Records a request on slot `id`.
    pub fn touch(&self, id: SlotId, now: Instant) {
        self.active.lock(|active| {
            if let Some(Some(entry)) = active.borrow_mut().get_mut(id) {
                entry.last = now;
            }
        });
    }

    /// Frees slot `id`.
    pub fn close(&self, id: SlotId) {
        self.active.lock(|active| {
            if let Some(slot) = active.borrow_mut().get_mut(id) {
                *slot = None;
            }
        });
    }

    /// Tells every open session to close (the board lost its link).
    pub fn evict_all(&self) {
        let open = self.active.lock(|active| active.borrow().map(|slot| slot.is_some()));
        for (signal, _) in self.evict.iter().zip(open).filter(|&(_, open)| open) {
            signal.signal(());
        }
    }

    /// Closes the sessions a new configuration no longer admits: clients
    /// outside `access`'s connect list, clients that could write and are
    /// outside its write list now (they may come back, read-only), and the
    /// idlest sessions beyond `max`. Returns how many were told to close.
    pub fn enforce(&self, access: &Access, max: usize) -> usize {
        let mut closing = [false; SLOT_COUNT];
        self.active.lock(|active| {
            let active = active.borrow();
            let mut kept = 0;
            for ((entry, close), _) in active.iter().zip(closing.iter_mut()).zip(0..) {
                if let Some(entry) = entry {
                    let admitted = access.may_connect(entry.peer)
                        && (entry.rights < Rights::ReadWrite || access.may_write(entry.peer));
                    *close = !admitted;
                    kept += usize::from(admitted);
                }
            }
            // Beyond the limit: the idlest of those kept go first.
            while kept > max {
                let idlest = active
                    .iter()
                    .zip(closing.iter())
                    .enumerate()
                    .filter_map(|(id, (entry, close))| entry.filter(|_| !close).map(|entry| (entry.last, id)))
                    .min();
                let Some((_, id)) = idlest else { break };
                if let Some(close) = closing.get_mut(id) {
                    *close = true;
                }
                kept -= 1;
            }
        });
        let mut told = 0;
        for (signal, _) in self.evict.iter().zip(closing).filter(|&(_, close)| close) {
            signal.signal(());
            told += 1;
        }
        told
    }

    /// Tells the open sessions in `slots` to close. Returns how many.
    pub fn evict_range(&self, slots: core::ops::Range<SlotId>) -> usize {
        let open = self.active.lock(|active| active.borrow().map(|slot| slot.is_some()));
        let mut told = 0;
        for (id, (signal, open)) in self.evict.iter().zip(open).enumerate() {
            if open && slots.contains(&id) {
                signal.signal(());
                told += 1;
            }
        }
        told
    }

    /// When the newest request (or connection) on any open session arrived.
    pub fn last_activity(&self) -> Option<Instant> {
        self.active.lock(|active| active.borrow().iter().flatten().map(|entry| entry.last).max())
    }

    /// What slot `id`'s client may do (for a slot not open, as a test serves
    /// a stream without a listener, no restriction: [`Rights::ReadWrite`]).
    pub fn rights(&self, id: SlotId) -> Rights {
        self.active
            .lock(|active| active.borrow().get(id).copied().flatten().map_or(Rights::ReadWrite, |entry| entry.rights))
    }

    /// The open sessions, by slot (`None`: a listening slot).
    pub fn sessions(&self) -> [Option<Session>; SLOT_COUNT] {
        self.active.lock(|active| {
            active
                .borrow()
                .map(|slot| slot.map(|entry| Session { peer: entry.peer, last: entry.last, rights: entry.rights }))
        })
    }

    /// Sessions open now.
    pub fn open_count(&self) -> usize {
        self.active.lock(|active| active.borrow().iter().filter(|s| s.is_some()).count())
    }

    /// Resolves when slot `id`'s session must close to make room.
    pub async fn evicted(&self, id: SlotId) {
        match self.evict.get(id) {
            Some(signal) => signal.wait().await,
            None => core::future::pending().await,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PEER: [u8; 4] = [198, 18, 0, 1];

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    #[test]
    fn a_new_configuration_closes_who_it_no_longer_admits() {
        let slots = Slots::new();
        slots.open(0, 8, at(1), [10, 0, 0, 1], Rights::ReadWrite);
        slots.open(1, 8, at(2), [10, 0, 0, 2], Rights::Read);
        slots.open(2, 8, at(3), [10, 0, 1, 3], Rights::ReadWrite);
        slots.open(3, 8, at(4), [10, 0, 0, 4], Rights::ReadWrite);
        let only =
            |address, prefix| crate::server::AllowList::EMPTY.with(crate::server::Network::new(address, prefix)?);
        // Writers outside 10.0.0.0/24 must go; the read-only client may stay.
        let access = Access { connect: None, write: only([10, 0, 0, 0], 24) };
        assert_eq!(slots.enforce(&access, 8), 1);
        assert!(slots.evict[2].signaled() && !slots.evict[0].signaled() && !slots.evict[1].signaled());
        slots.close(2);
        // Nobody outside 10.0.0.0/31 may connect: 10.0.0.2 and 10.0.0.4 go.
        let access = Access { connect: only([10, 0, 0, 0], 31), write: None };
        assert_eq!(slots.enforce(&access, 8), 2);
        assert!(slots.evict[1].signaled() && slots.evict[3].signaled() && !slots.evict[0].signaled());
    }

    #[test]
    fn a_lower_limit_closes_the_idlest() {
        let slots = Slots::new();
        for id in 0..4 {
            slots.open(id, 8, at(10 * id as u64), PEER, Rights::ReadWrite);
        }
        slots.touch(0, at(100));
        assert_eq!(slots.enforce(&Access::OPEN, 2), 2);
        let closed: Vec<bool> = (0..4).map(|id| slots.evict[id].signaled()).collect();
        assert_eq!(closed, [false, true, true, false], "1 and 2 were the idlest");
        assert_eq!(slots.enforce(&Access::OPEN, 8), 0);
    }

    #[test]
    fn the_idlest_session_makes_room() {
        let slots = Slots::new();
        for id in 0..8 {
            assert_eq!(slots.open(id, 8, at(100 + id as u64), PEER, Rights::ReadWrite), None);
        }
        slots.touch(0, at(1_000)); // slot 1 is now the idlest
        assert_eq!(slots.open(8, 8, at(2_000), PEER, Rights::ReadWrite), Some(1));
        assert!(slots.evict[1].signaled());
        assert!(!slots.evict[0].signaled());
        slots.close(1);
        assert_eq!(slots.open_count(), 8);
    }

    #[test]
    fn a_reused_slot_forgets_an_old_eviction() {
        let slots = Slots::new();
        slots.open(0, 1, at(0), PEER, Rights::ReadWrite);
        assert_eq!(slots.open(1, 1, at(10), PEER, Rights::ReadWrite), Some(0));
        slots.close(0);
        assert_eq!(slots.open(0, 1, at(20), PEER, Rights::ReadWrite), Some(1));
        assert!(!slots.evict[0].signaled(), "slot 0's new session is not evicted");
        assert!(slots.evict[1].signaled());
    }

    #[test]
    fn each_session_keeps_its_clients_rights() {
        let slots = Slots::new();
        slots.open(0, 8, at(0), PEER, Rights::Read);
        slots.open(1, 8, at(0), PEER, Rights::ReadWrite);
        assert_eq!((slots.rights(0), slots.rights(1)), (Rights::Read, Rights::ReadWrite));
        assert_eq!(
            (slots.rights(2), slots.rights(SLOT_COUNT)),
            (Rights::ReadWrite, Rights::ReadWrite),
            "no session, no restriction"
        );
        let sessions = slots.sessions();
        assert_eq!(sessions[0], Some(Session { peer: PEER, last: at(0), rights: Rights::Read }));
        assert_eq!(sessions[1], Some(Session { peer: PEER, last: at(0), rights: Rights::ReadWrite }));
        assert!(sessions[2..].iter().all(Option::is_none));
        slots.close(0);
        slots.open(0, 8, at(1), PEER, Rights::ReadWrite);
        assert_eq!(slots.rights(0), Rights::ReadWrite, "a new client on the same slot has its own rights");
    }

    #[test]
    fn evict_all_reaches_open_sessions_only() {
        let slots = Slots::new();
        assert_eq!(slots.last_activity(), None);
        slots.open(0, 8, at(5), PEER, Rights::ReadWrite);
        slots.open(2, 8, at(7), PEER, Rights::ReadWrite);
        slots.touch(0, at(9));
        assert_eq!(slots.last_activity(), Some(at(9)));
        slots.evict_all();
        assert!(slots.evict[0].signaled());
        assert!(!slots.evict[1].signaled(), "a listening slot has no session to close");
        assert!(slots.evict[2].signaled());
        slots.close(0);
        assert_eq!(slots.last_activity(), Some(at(7)));
    }

    #[test]
    fn out_of_range_ids_are_ignored() {
        let slots = Slots::new();
        assert_eq!(slots.open(SLOT_COUNT, 1, at(0), PEER, Rights::ReadWrite), None);
        slots.touch(SLOT_COUNT, at(0));
        slots.close(SLOT_COUNT);
        assert_eq!(slots.open_count(), 0);
    }
}
