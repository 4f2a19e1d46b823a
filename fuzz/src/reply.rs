//! The robot link's reply check ([`modbus::client`]): arbitrary bytes as
//! the reply to a Read Holding Registers request, against an oracle
//! written from the specification here.

use modbus::client::ReadHoldingRegisters;
use modbus::mbap;

/// The request's fields a fuzz input starts with: transaction id (2), unit
/// id (1), start (2), quantity (1: 1-125 as `byte % 125 + 1`), then the reply.
pub const HEADER_LEN: usize = 6;

/// An input: the request asked, then the reply bytes.
pub fn encode(request: &ReadHoldingRegisters, reply: &[u8]) -> Vec<u8> {
    let mut input = Vec::new();
    input.extend(request.transaction_id.to_be_bytes());
    input.push(request.unit_id);
    input.extend(request.start.to_be_bytes());
    input.push(u8::try_from(request.quantity.saturating_sub(1)).unwrap_or(0));
    input.extend(reply);
    input
}

/// The reply a well-behaved server sends to `request`, with `values`.
pub fn good_reply(request: &ReadHoldingRegisters, values: impl Iterator<Item = u16>) -> Vec<u8> {
    let count = 2 * request.quantity;
    let mut reply = Vec::new();
    reply.extend(request.transaction_id.to_be_bytes());
    reply.extend([0, 0]);
    reply.extend((count + 3).to_be_bytes());
    reply.extend([request.unit_id, 0x03, count as u8]);
    reply.extend(values.take(usize::from(request.quantity)).flat_map(u16::to_be_bytes));
    reply
}

/// Checks the parser on `data` (see [`HEADER_LEN`]): it never panics, it
/// accepts exactly the one reply the oracle accepts, and what it returns
/// is the reply's register bytes.
pub fn reply(data: &[u8]) {
    let Some((head, bytes)) = data.split_at_checked(HEADER_LEN) else { return };
    let &[t0, t1, unit_id, s0, s1, q] = head else { return };
    let quantity = u16::from(q) % 125 + 1;
    let request = ReadHoldingRegisters {
        transaction_id: u16::from_be_bytes([t0, t1]),
        unit_id,
        start: u16::from_be_bytes([s0, s1]),
        quantity,
    };
    let count = 2 * usize::from(quantity);
    let accepted = bytes.len() == 9 + count
        && bytes[..2] == [t0, t1]
        && bytes[2..4] == [0, 0]
        && bytes[4..6] == u16::try_from(3 + count).unwrap().to_be_bytes()
        && bytes[6] == unit_id
        && bytes[7] == 0x03
        && usize::from(bytes[8]) == count;
    match request.parse_reply(bytes) {
        Ok(registers) => {
            assert!(accepted, "accepted a reply the specification refuses: {bytes:02x?}");
            assert_eq!(registers.len(), usize::from(quantity));
            let values: Vec<u8> = registers.iter().flat_map(u16::to_be_bytes).collect();
            assert_eq!(values, bytes[9..], "the registers are the reply's bytes");
        }
        Err(e) => assert!(!accepted, "refused a good reply ({e}): {bytes:02x?}"),
    }
    // The stream framing the link uses first never panics, and a frame it
    // delimits is judged the same way.
    if let Ok(Some(len)) = mbap::next_frame_len(bytes) {
        let _ = request.parse_reply(&bytes[..len]);
    }
}

/// Seeds: the robot link's two reads answered well, an exception, and a fixture's reply.
pub fn seeds() -> Vec<Vec<u8>> {
    let head = ReadHoldingRegisters { transaction_id: 1, unit_id: 1, start: 256, quantity: 60 };
    let task = ReadHoldingRegisters { transaction_id: 2, unit_id: 1, start: 400, quantity: 36 };
    let small = ReadHoldingRegisters { transaction_id: 0x1234, unit_id: 7, start: 0, quantity: 3 };
    vec![
        encode(&head, &good_reply(&head, (0..).map(|i: u16| i.wrapping_mul(257)))),
        encode(&task, &good_reply(&task, std::iter::repeat(0x8000))),
        encode(&small, &good_reply(&small, [2, 11, 3].into_iter())),
        encode(&small, &[0x12, 0x34, 0, 0, 0, 3, 7, 0x83, 0x04]),
        encode(&small, &[0x12, 0x35, 0, 0, 0, 9, 7, 0x03, 6, 0, 2, 0, 11, 0, 3]),
    ]
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_seeds_pass() {
        for seed in super::seeds() {
            super::reply(&seed);
        }
    }
}
