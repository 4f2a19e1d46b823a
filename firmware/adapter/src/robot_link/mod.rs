//! The robot link (docs/robot-link.md): the adapter as the gateway of the
//! real robot controller. One Modbus TCP client connection to `robot.link`
//! reads the robot's points every `robot.poll_ms` and puts each poll into
//! the image whole; the masters read them from the image, never from the
//! controller (docs/robot-link.md).
//!
//! - A poll is two FC 03 reads: 256-315 (60 registers: the version, the
//!   state and flags, the reserved 265-269 and the joints, which the map
//!   holds with gaps that read 0) and 400-435 (36: the task and tool
//!   values). 256-435 in one would be 180 registers, over the 125 a read may
//!   ask for, and 316-399 are not the robot's; two is the fewest. The
//!   reserved registers in a reply are ignored (the image keeps them 0).
//! - Every reply is checked strictly ([`modbus::client`]), and the robot's
//!   status registers must hold values their encodings allow: anything else
//!   is a failed poll. A poll is applied in one [`Device::update`] or not at
//!   all, so a master never reads points of two polls in one read.
//! - A request that takes longer than 2 x `poll_ms` (at least
//!   [`MIN_TIMEOUT`]) fails. An exception reply leaves the connection as it
//!   is; any other failure closes it (the stream may be out of step), and
//!   the next attempt connects again.
//! - **Link down** after [`FAILED_POLLS_FOR_DOWN`] failed polls in a row, or
//!   while there is no connection: the robot's points read as with no source
//!   (NOT READY, zeros). Connection attempts back off from [`BACKOFF_FIRST`]
//!   doubling to [`BACKOFF_MAX`]; a good poll starts the back-off afresh.
//! - The link only reads: nothing a master writes reaches the controller.
//!
//! [`Link`] is what the tasks share: the target and period in force (which
//! the settings change at once, [`Link::configure`]) and the link's health.
//! [`run`] is the task's body; [`Gated`] keeps the board's own robot source
//! (hal-sim's simulated robot) off the robot's points while a link is set.

use core::cell::RefCell;

use embassy_futures::select::{Either, select};
use embassy_net::tcp::TcpSocket;
use embassy_net::{IpEndpoint, Ipv4Address, Stack};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer, with_timeout};
use embedded_io_async::Write as _;

use crate::device::Device;
use crate::io::{Robot, RobotSample, RobotStatus, Telemetry, Version};
use crate::map::table::{self, reg};
use crate::map::{Image, Permission};
use crate::modbus::client::{REQUEST_ADU_LEN, ReadHoldingRegisters, ReplyError};
use crate::modbus::mbap::{self, MAX_ADU_LEN};
use crate::modbus::pdu::MAX_READ_REGISTERS;
use crate::server::CLOSE_TIMEOUT;
use crate::server::Stats;
use crate::settings::{RobotLink, RobotSettings};

/// The socket's receive buffer: one reply at a time, the largest ADU.
pub const LINK_RX_LEN: usize = MAX_ADU_LEN;
/// The socket's transmit buffer: one request at a time.
pub const LINK_TX_LEN: usize = 2 * REQUEST_ADU_LEN;
/// Failed polls in a row that take the link down.
pub const FAILED_POLLS_FOR_DOWN: u8 = 3;
/// The shortest time a request may take before it fails (docs/robot-link.md: 2 x `poll_ms`, at least 200 ms).
pub const MIN_TIMEOUT: Duration = Duration::from_millis(200);
/// The first wait before connecting again.
pub const BACKOFF_FIRST: Duration = Duration::from_millis(100);
/// The longest wait before connecting again.
pub const BACKOFF_MAX: Duration = Duration::from_secs(5);

/// One FC 03 read of a poll.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Block {
    pub start: u16,
    pub quantity: u16,
}

/// Registers 256-315: version, state and flags, reserved 265-269, the joints.
pub const HEAD: Block = Block { start: reg::CONTROLLER_VERSION, quantity: HEAD_LEN as u16 };
/// Registers 400-435: task pose and velocity, tool offset, external wrench.
pub const TASK: Block = Block { start: reg::TASK_POSITION, quantity: TASK_LEN as u16 };
const _: () = assert!(HEAD.quantity <= MAX_READ_REGISTERS && TASK.quantity <= MAX_READ_REGISTERS);
const HEAD_LEN: usize = (reg::JOINT_TORQUE + 5 - reg::CONTROLLER_VERSION + 1) as usize;
const TASK_LEN: usize = (table::reg::LAST - reg::TASK_POSITION + 1) as usize;

/// One poll's registers, as the controller sent them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Snapshot {
    /// [`HEAD`].
    pub head: [u16; HEAD_LEN],
    /// [`TASK`].
    pub task: [u16; TASK_LEN],
}

impl Snapshot {
    /// All zeros.
    pub const ZERO: Self = Self { head: [0; HEAD_LEN], task: [0; TASK_LEN] };

    /// Whether every point holds a value its encoding allows (the state is
    /// 0-10 or 15, the flags 0 or 1, ...); reserved registers are not looked at.
    pub fn makes_sense(&self) -> bool {
        let blocks = [(HEAD.start, &self.head[..]), (TASK.start, &self.task[..])];
        blocks.into_iter().all(|(start, values)| {
            (start..=u16::MAX).zip(values).all(|(address, &value)| {
                table::register_row(address)
                    .is_none_or(|row| row.access == Permission::Reserved || row.encoding.accepts(value, 0))
            })
        })
    }

    /// Puts the poll into the image (the reserved registers stay 0).
    pub fn apply(&self, image: &mut Image) {
        image.set_registers(HEAD.start, &self.head);
        image.set_registers(TASK.start, &self.task);
    }
}

/// The robot's points with no source: NOT READY, zeros, version 0.0.0.
pub fn apply_no_source(image: &mut Image) {
    image.set_controller_version(&Version::NONE);
    image.set_robot_status(&RobotStatus::NOT_READY);
    image.set_telemetry(&Telemetry::default());
}

/// The poll's timeout for a period: 2 x `poll`, at least [`MIN_TIMEOUT`].
pub fn timeout(poll: Duration) -> Duration {
    Duration::from_ticks(poll.as_ticks().saturating_mul(2)).max(MIN_TIMEOUT)
}

/// The link's health, as `/api/status` and the page show it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Health {
    /// The controller in force (`None`: no link).
    pub target: Option<RobotLink>,
    /// The link is up: connected, and fewer than [`FAILED_POLLS_FOR_DOWN`]
    /// polls in a row failed since a good one.
    pub up: bool,
    /// A connection to the controller is open now.
    pub connected: bool,
    /// Polls applied since start-up.
    pub polls: u32,
    /// Polls failed since start-up.
    pub errors: u32,
    /// When the last good poll was applied.
    pub last_ok: Option<Instant>,
}

/// The mutable part of [`Link`].
#[derive(Clone, Copy, Debug)]
struct State {
    status: Health,
    poll: Duration,
    failed_in_a_row: u8,
}

/// What the link task, the settings and the status share.
pub struct Link {
    state: Mutex<CriticalSectionRawMutex, RefCell<State>>,
    /// The target changed: the task drops its connection and starts again.
    changed: Signal<CriticalSectionRawMutex, ()>,
}

impl core::fmt::Debug for Link {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Link").field("status", &self.health()).finish_non_exhaustive()
    }
}

impl Default for Link {
    fn default() -> Self {
        Self::new()
    }
}

impl Link {
    /// No link set, down, nothing counted.
    pub const fn new() -> Self {
        let status = Health { target: None, up: false, connected: false, polls: 0, errors: 0, last_ok: None };
        let state = State { status, poll: Duration::from_millis(100), failed_in_a_row: FAILED_POLLS_FOR_DOWN };
        Self { state: Mutex::new(RefCell::new(state)), changed: Signal::new() }
    }

    /// Puts `robot` (the settings' `robot` group) in force at once: a new
    /// target makes the task connect to it afresh (the link is down until
    /// its first good poll); a new period applies from the next poll.
    pub fn configure(&self, robot: &RobotSettings) {
        let changed = self.state.lock(|state| {
            let state = &mut *state.borrow_mut();
            state.poll = Duration::from_millis(u64::from(robot.poll_ms.max(1)));
            let changed = state.status.target != robot.link;
            state.status.target = robot.link;
            changed
        });
        if changed {
            info!("robot link: {}", if robot.link.is_some() { "set" } else { "none" });
            self.changed.signal(());
        }
    }

    /// Whether a link is set: then it is the robot source, whatever its health.
    pub fn is_set(&self) -> bool {
        self.state.lock(|state| state.borrow().status.target.is_some())
    }

    /// The link's health now.
    pub fn health(&self) -> Health {
        self.state.lock(|state| state.borrow().status)
    }

    fn target_and_period(&self) -> Option<(RobotLink, Duration)> {
        self.state.lock(|state| {
            let state = state.borrow();
            state.status.target.map(|target| (target, state.poll))
        })
    }

    fn period(&self) -> Duration {
        self.state.lock(|state| state.borrow().poll)
    }

    fn set_connected(&self, connected: bool) {
        self.state.lock(|state| state.borrow_mut().status.connected = connected);
    }

    /// A good poll: applied whole, under the image lock, and counted.
    fn good(&self, device: &Device<'_>, snapshot: &Snapshot) {
        let was_up = device.update(|image| {
            snapshot.apply(image);
            self.state.lock(|state| {
                let state = &mut *state.borrow_mut();
                let was_up = state.status.up;
                state.failed_in_a_row = 0;
                state.status.up = true;
                state.status.polls = state.status.polls.wrapping_add(1);
                state.status.last_ok = Some(Instant::now());
                was_up
            })
        });
        Stats::count(&device.stats().robot_polls);
        if !was_up {
            info!("robot link: up");
        }
    }

    /// A failed poll (or connection attempt): counted; the link goes down
    /// at the [`FAILED_POLLS_FOR_DOWN`]th in a row, or at once without a
    /// connection. While down, each failure re-asserts the no-source points.
    fn failed(&self, device: &Device<'_>, connected: bool) {
        let went_down = device.update(|image| {
            let (was_up, down) = self.state.lock(|state| {
                let state = &mut *state.borrow_mut();
                state.status.errors = state.status.errors.wrapping_add(1);
                state.status.connected = connected;
                state.failed_in_a_row = state.failed_in_a_row.saturating_add(1);
                let was_up = state.status.up;
                let down = !connected || state.failed_in_a_row >= FAILED_POLLS_FOR_DOWN;
                if down {
                    state.status.up = false;
                }
                (was_up, down)
            });
            if down {
                apply_no_source(image);
            }
            was_up && down
        });
        Stats::count(&device.stats().robot_errors);
        if went_down {
            Stats::count(&device.stats().robot_link_downs);
            warn!("robot link: down");
        }
    }

    /// The target changed or went: down at once, the no-source points.
    fn reset(&self, device: &Device<'_>) {
        device.update(|image| {
            self.state.lock(|state| {
                let state = &mut *state.borrow_mut();
                state.status.up = false;
                state.status.connected = false;
                state.failed_in_a_row = FAILED_POLLS_FOR_DOWN;
            });
            apply_no_source(image);
        });
    }
}

/// A board's own robot source, kept off the robot's points while a link is
/// set (the link wins; docs/robot-link.md).
#[derive(Debug)]
pub struct Gated<'a, R> {
    link: &'a Link,
    robot: R,
}

impl<'a, R: Robot> Gated<'a, R> {
    pub fn new(link: &'a Link, robot: R) -> Self {
        Self { link, robot }
    }
}

impl<R: Robot> Robot for Gated<'_, R> {
    fn status(&mut self) -> RobotStatus {
        self.robot.status()
    }

    fn telemetry(&mut self) -> Telemetry {
        self.robot.telemetry()
    }

    fn version(&mut self) -> Version {
        self.robot.version()
    }

    fn sample(&mut self) -> Option<RobotSample> {
        if self.link.is_set() { None } else { self.robot.sample() }
    }
}

/// Why a poll failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum Failure {
    /// The socket failed or the controller closed the connection.
    Io,
    /// No whole reply within the timeout.
    Timeout,
    /// The reply is not the answer to the request.
    Reply(ReplyError),
    /// The reply is well formed but a point holds a value it cannot hold.
    Nonsense,
}

impl Failure {
    /// Whether the stream is still in step after it (an exception reply, a
    /// value that makes no sense): then the connection is kept.
    fn keeps_connection(self) -> bool {
        matches!(self, Self::Reply(ReplyError::Exception(_)) | Self::Nonsense)
    }
}

/// How one connection ended.
enum Ended {
    /// The settings changed the target.
    Changed,
    /// The connection failed or was closed; `good` if it carried a good poll.
    Lost { good: bool },
}

/// The link task's body: follows the target in force forever. Each board
/// wraps it in a task of its own; the socket's buffers live in this future
/// (the task's static memory).
pub async fn run(stack: Stack<'_>, device: &Device<'_>, link: &Link) -> ! {
    let mut rx = [0u8; LINK_RX_LEN];
    let mut tx = [0u8; LINK_TX_LEN];
    let mut transaction: u16 = 0;
    let mut backoff = BACKOFF_FIRST;
    loop {
        let Some((target, _)) = link.target_and_period() else {
            // No link (a change to none was reset below): the board's source feeds the points.
            link.changed.wait().await;
            continue;
        };
        let ended =
            {
                let mut socket = TcpSocket::new(stack, &mut rx, &mut tx);
                let ended =
                    match select(link.changed.wait(), connection(&mut socket, device, link, target, &mut transaction))
                        .await
                    {
                        Either::First(()) => Ended::Changed,
                        Either::Second(ended) => ended,
                    };
                link.set_connected(false);
                socket.abort();
                let _ = with_timeout(CLOSE_TIMEOUT, socket.flush()).await;
                ended
            };
        match ended {
            Ended::Changed => {
                link.reset(device);
                backoff = BACKOFF_FIRST;
            }
            Ended::Lost { good } => {
                if good {
                    backoff = BACKOFF_FIRST;
                }
                debug!("robot link: connecting again in {} ms", backoff.as_millis());
                if let Either::First(()) = select(link.changed.wait(), Timer::after(backoff)).await {
                    link.reset(device);
                    backoff = BACKOFF_FIRST;
                    continue;
                }
                backoff = (backoff * 2).min(BACKOFF_MAX);
            }
        }
    }
}

/// One connection: connect, then poll every period until a failure that
/// loses the stream.
async fn connection(
    socket: &mut TcpSocket<'_>,
    device: &Device<'_>,
    link: &Link,
    target: RobotLink,
    transaction: &mut u16,
) -> Ended {
    let endpoint = IpEndpoint::new(Ipv4Address::from(target.address).into(), target.port);
    let limit = timeout(link.period());
    socket.set_timeout(Some(BACKOFF_MAX.max(limit)));
    if !matches!(with_timeout(limit, socket.connect(endpoint)).await, Ok(Ok(()))) {
        link.failed(device, false);
        return Ended::Lost { good: false };
    }
    link.set_connected(true);
    let mut good = false;
    let mut next = Instant::now();
    loop {
        Timer::at(next).await;
        let period = link.period();
        next += period;
        let now = Instant::now();
        if next < now {
            // A poll took longer than the period: the next one a period from now, no burst.
            next = now + period;
        }
        match poll(socket, target.unit, transaction, timeout(period)).await {
            Ok(snapshot) => {
                link.good(device, &snapshot);
                good = true;
            }
            Err(failure) => {
                debug!("robot link: poll failed: {:?}", failure);
                link.failed(device, true);
                if !failure.keeps_connection() {
                    return Ended::Lost { good };
                }
            }
        }
    }
}

/// One poll: both reads, each within `limit`, and the check of the values.
async fn poll(
    socket: &mut TcpSocket<'_>,
    unit: u8,
    transaction: &mut u16,
    limit: Duration,
) -> Result<Snapshot, Failure> {
    let mut snapshot = Snapshot::ZERO;
    for (block, out) in [(HEAD, &mut snapshot.head[..]), (TASK, &mut snapshot.task[..])] {
        *transaction = transaction.wrapping_add(1);
        let request = ReadHoldingRegisters {
            transaction_id: *transaction,
            unit_id: unit,
            start: block.start,
            quantity: block.quantity,
        };
        with_timeout(limit, exchange(socket, &request, out)).await.map_err(|_| Failure::Timeout)??;
    }
    if snapshot.makes_sense() { Ok(snapshot) } else { Err(Failure::Nonsense) }
}

/// Sends `request` and reads its reply, framed by its length field only, into `out`.
async fn exchange(socket: &mut TcpSocket<'_>, request: &ReadHoldingRegisters, out: &mut [u16]) -> Result<(), Failure> {
    let mut frame = [0u8; MAX_ADU_LEN];
    let len = request.emit(&mut frame).ok_or(Failure::Io)?;
    socket.write_all(frame.get(..len).unwrap_or_default()).await.map_err(|_| Failure::Io)?;
    let mut filled = 0;
    loop {
        let Some(free) = frame.get_mut(filled..).filter(|free| !free.is_empty()) else {
            return Err(Failure::Reply(ReplyError::TrailingBytes));
        };
        let read = socket.read(free).await.map_err(|_| Failure::Io)?;
        if read == 0 {
            return Err(Failure::Io);
        }
        filled += read;
        let received = frame.get(..filled).unwrap_or_default();
        match mbap::next_frame_len(received) {
            Ok(None) => continue,
            Ok(Some(_)) => {
                // parse_reply refuses bytes past the frame: one request, one reply.
                let registers = request.parse_reply(received).map_err(Failure::Reply)?;
                registers.copy_to(out);
                return Ok(());
            }
            Err(e) => return Err(Failure::Reply(ReplyError::Framing(e))),
        }
    }
}

#[cfg(test)]
mod tests;
