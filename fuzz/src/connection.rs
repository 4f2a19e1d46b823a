//! The session target's connection: test-support's in-memory duplex, shaped
//! as the input says. The client's bytes are all there from the start and
//! the client has closed its side, so a session must answer everything and
//! end without waiting for time to pass.

use test_support::duplex::{ServerEnd, Wire};

use crate::input::{PARTIAL_WRITES, STALL_READS, SessionInput};

/// A connection carrying `input`'s stream: reads take the cut sizes in turn
/// (0: as much as the buffer holds); with [`STALL_READS`] each read is
/// `Pending` once first; with [`PARTIAL_WRITES`] each write is `Pending` once,
/// then takes `1 + cut % 16` bytes, the cuts in turn.
pub fn connect(input: &SessionInput<'_>) -> (Wire, ServerEnd) {
    let connection =
        shaped(input.stream, input.cuts, input.flags & STALL_READS != 0, input.flags & PARTIAL_WRITES != 0);
    connection.0.close();
    connection
}

/// A connection carrying `stream`, shaped as [`connect`] says, the client's
/// side still open (the caller closes it or not): the session and the http
/// targets' one way to cut a stream.
pub fn shaped(stream: &[u8], cuts: &[u8], stall_reads: bool, partial_writes: bool) -> (Wire, ServerEnd) {
    let (wire, end) = Wire::new();
    wire.read_sizes(cuts.iter().map(|&cut| usize::from(cut)));
    wire.stall_reads(stall_reads);
    if partial_writes {
        let sizes: Vec<usize> = match cuts {
            [] => vec![1],
            cuts => cuts.iter().map(|&cut| 1 + usize::from(cut % 16)).collect(),
        };
        wire.write_sizes(sizes);
        wire.stall_writes(true);
    }
    wire.send(stream);
    (wire, end)
}
