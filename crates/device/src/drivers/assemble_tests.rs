//! The receive cores against independent oracles: the standard library's `chunks` and `split` on the whole
//! stream at once, whatever pieces the port delivers it in; and the vendors' own reply shapes.

use super::*;
use proptest::prelude::*;

fn feed<R: Receive>(core: &mut R, mut piece: &[u8], mut take: impl FnMut(&mut R)) {
    while !piece.is_empty() {
        let space = core.space();
        let n = space.len().min(piece.len());
        space[..n].copy_from_slice(&piece[..n]);
        core.filled(n);
        piece = &piece[n..];
        take(core);
    }
}

/// Haply's board answers a torque command with `[device id][f32 LE][f32 LE]` (hAPI Board.receive: a buffer of
/// 1 + 4 * expected bytes, byte 0 the device id, then the floats least significant byte first): two replies
/// sent back to back come out as two replies, never shifted.
#[test]
fn two_haply_replies_back_to_back_come_out_whole() {
    let mut stream = vec![5u8];
    stream.extend_from_slice(&241.0f32.to_le_bytes());
    stream.extend_from_slice(&(-61.0f32).to_le_bytes());
    stream.push(5);
    stream.extend_from_slice(&1.5f32.to_le_bytes());
    stream.extend_from_slice(&2.5f32.to_le_bytes());
    let mut core = FixedAssembler::<9>::new();
    let mut out = Vec::new();
    feed(&mut core, &stream, |c| out.extend(c.next_reply()));
    assert_eq!(out.len(), 2);
    assert_eq!(out[0][0], 5);
    assert_eq!(f32::from_le_bytes(out[0][1..5].try_into().unwrap()), 241.0);
    assert_eq!(f32::from_le_bytes(out[1][5..9].try_into().unwrap()), 2.5);
}

/// The WoodenHaptics firmware prints `[%d,%d,%d,%d,%d,%d,%d,%d]\n` (woody_teensy_mini.ino:108): a line in two
/// pieces comes out once, whole, without its `\n`.
#[test]
fn a_woodenhaptics_report_split_in_two_comes_out_once() {
    let mut core = LineAssembler::<256>::new();
    let mut out = Vec::new();
    feed(&mut core, b"[3,100,-2", |c| {
        while let Some(Line::Whole(line)) = c.next_line() {
            out.push(line.to_vec());
        }
    });
    assert!(out.is_empty());
    feed(&mut core, b"00,300,0,30,0,0]\n", |c| {
        while let Some(Line::Whole(line)) = c.next_line() {
            out.push(line.to_vec());
        }
    });
    assert_eq!(out, vec![b"[3,100,-200,300,0,30,0,0]".to_vec()]);
}

#[test]
fn a_line_longer_than_the_buffer_is_dropped_and_said() {
    let mut core = LineAssembler::<8>::new();
    let mut seen = Vec::new();
    feed(&mut core, b"0123456789\nab\n", |c| {
        while let Some(line) = c.next_line() {
            seen.push(match line {
                Line::Whole(l) => String::from_utf8_lossy(l).into_owned(),
                Line::TooLong => "too long".to_owned(),
            });
        }
    });
    // The first 8 bytes are dropped as too long; the rest of that line ("89") ends at its `\n`.
    assert_eq!(seen, vec!["too long", "89", "ab"]);
}

proptest! {
    /// Whatever pieces the stream comes in, the fixed-length core yields exactly `stream.chunks_exact(9)`.
    #[test]
    fn fixed_replies_match_chunks_exact(stream in prop::collection::vec(any::<u8>(), 0..200),
                                        cuts in prop::collection::vec(1usize..20, 1..40)) {
        let mut core = FixedAssembler::<9>::new();
        let mut out: Vec<[u8; 9]> = Vec::new();
        let mut rest = stream.as_slice();
        for cut in cuts.iter().cycle() {
            if rest.is_empty() { break; }
            let n = (*cut).min(rest.len());
            feed(&mut core, &rest[..n], |c| out.extend(c.next_reply()));
            rest = &rest[n..];
        }
        let expected: Vec<[u8; 9]> = stream.chunks_exact(9).map(|c| c.try_into().unwrap()).collect();
        prop_assert_eq!(out, expected);
        prop_assert_eq!(core.held(), stream.len() % 9);
    }

    /// Whatever pieces the stream comes in, the line core yields the `\n`-ended pieces of `split`.
    #[test]
    fn lines_match_split(lines in prop::collection::vec(prop::collection::vec(0x20u8..0x7f, 0..40), 0..12),
                         cuts in prop::collection::vec(1usize..30, 1..40)) {
        let mut stream = Vec::new();
        for line in &lines {
            stream.extend_from_slice(line);
            stream.push(b'\n');
        }
        let mut core = LineAssembler::<64>::new();
        let mut out = Vec::new();
        let mut rest = stream.as_slice();
        for cut in cuts.iter().cycle() {
            if rest.is_empty() { break; }
            let n = (*cut).min(rest.len());
            feed(&mut core, &rest[..n], |c| {
                while let Some(line) = c.next_line() {
                    if let Line::Whole(l) = line { out.push(l.to_vec()); }
                }
            });
            rest = &rest[n..];
        }
        let expected: Vec<Vec<u8>> = stream.split(|&b| b == b'\n').map(<[u8]>::to_vec).collect();
        // `split` yields an empty piece after the last `\n`.
        prop_assert_eq!(out, expected[..expected.len() - 1].to_vec());
    }
}
