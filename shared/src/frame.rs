//! Framing: `COBS( seq:u16 LE | postcard payload | crc32 LE ) 0x00`.
//!
//! Klipper's stance, since a controller may sit behind a plain UART: every frame carries a sequence
//! number and a CRC; a bad frame is dropped, counted and NAKed, never half-used. The 0x00 delimiter
//! lets the decoder resynchronise after any garbage: whatever precedes a 0x00 is one candidate
//! frame, accepted only if COBS, length, CRC and payload all check out.
//!
//! CRC-32/ISCSI (Castagnoli): Hamming distance 4 up to ~2 kbit of payload, far beyond our frames.

use crc::{Crc, CRC_32_ISCSI};
use serde::{de::DeserializeOwned, Serialize};

/// Largest postcard payload of any message (checked against the largest messages in `msg`'s tests).
pub const MAX_PAYLOAD: usize = 192;
const SEQ_LEN: usize = 2;
const CRC_LEN: usize = 4;
/// Largest frame before COBS: sequence number + payload + CRC.
pub const MAX_RAW_FRAME: usize = SEQ_LEN + MAX_PAYLOAD + CRC_LEN;
/// Largest frame on the wire: COBS adds one byte per 254 plus one; then the 0x00 delimiter.
pub const MAX_WIRE_FRAME: usize = MAX_RAW_FRAME + MAX_RAW_FRAME / 254 + 1 + 1;

const CRC: Crc<u32> = Crc::<u32>::new(&CRC_32_ISCSI);

/// Why a frame could not be built or was dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error("frame CRC mismatch")]
    Crc,
    #[error("frame is not valid COBS")]
    Cobs,
    #[error("frame longer than {MAX_WIRE_FRAME} bytes")]
    TooLong,
    #[error("frame shorter than its header and CRC")]
    TooShort,
    #[error("frame payload is not a message of this protocol")]
    Payload,
    #[error("message does not fit in one frame")]
    Encode,
}

/// A decoded, checked frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame<M> {
    pub seq: u16,
    pub msg: M,
}

/// Encode `msg` with sequence number `seq` into `out`; returns the bytes written, 0x00 included.
pub fn encode<M: Serialize>(seq: u16, msg: &M, out: &mut [u8]) -> Result<usize, FrameError> {
    let mut raw = [0u8; MAX_RAW_FRAME];
    raw[..SEQ_LEN].copy_from_slice(&seq.to_le_bytes());
    let payload_len = postcard::to_slice(msg, &mut raw[SEQ_LEN..SEQ_LEN + MAX_PAYLOAD])
        .map_err(|_| FrameError::Encode)?
        .len();
    let body = SEQ_LEN + payload_len;
    let crc = CRC.checksum(&raw[..body]);
    raw[body..body + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
    let n = cobs::try_encode(&raw[..body + CRC_LEN], out).map_err(|_| FrameError::Encode)?;
    let delim = out.get_mut(n).ok_or(FrameError::Encode)?;
    *delim = 0;
    Ok(n + 1)
}

/// Counters of everything the decoder saw; the firmware reports them in its status.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecoderStats {
    pub ok: u32,
    pub bad_crc: u32,
    pub bad_cobs: u32,
    pub too_long: u32,
    pub too_short: u32,
    pub bad_payload: u32,
}

impl DecoderStats {
    /// Every frame dropped for any reason.
    pub fn bad(&self) -> u32 {
        self.bad_crc
            .saturating_add(self.bad_cobs)
            .saturating_add(self.too_long)
            .saturating_add(self.too_short)
            .saturating_add(self.bad_payload)
    }
}

/// Streaming frame decoder: feed it bytes in any chunking; it owns one bounded buffer, no globals.
pub struct FrameDecoder {
    buf: [u8; MAX_WIRE_FRAME],
    len: usize,
    /// The current candidate frame outgrew the buffer: discard until the next delimiter.
    overflowed: bool,
    stats: DecoderStats,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_WIRE_FRAME],
            len: 0,
            overflowed: false,
            stats: DecoderStats {
                ok: 0,
                bad_crc: 0,
                bad_cobs: 0,
                too_long: 0,
                too_short: 0,
                bad_payload: 0,
            },
        }
    }

    pub fn stats(&self) -> &DecoderStats {
        &self.stats
    }

    /// Forget a partial frame (e.g. after the link reconnects).
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflowed = false;
    }

    /// Feed one byte. Returns `Some` when a delimiter closed a candidate frame: the frame, or why it
    /// was dropped. Empty frames (consecutive delimiters, used to flush a line) are skipped silently.
    pub fn push<M: DeserializeOwned>(&mut self, byte: u8) -> Option<Result<Frame<M>, FrameError>> {
        if byte != 0 {
            if self.overflowed {
                return None;
            }
            // The delimiter is not stored, so a full frame needs MAX_WIRE_FRAME - 1 bytes.
            if self.len >= MAX_WIRE_FRAME - 1 {
                self.overflowed = true;
                return None;
            }
            self.buf[self.len] = byte;
            self.len += 1;
            return None;
        }
        let len = core::mem::replace(&mut self.len, 0);
        if core::mem::replace(&mut self.overflowed, false) {
            self.stats.too_long = self.stats.too_long.saturating_add(1);
            return Some(Err(FrameError::TooLong));
        }
        if len == 0 {
            return None;
        }
        let result = Self::check(&mut self.buf[..len]);
        let counter = match result {
            Ok(_) => &mut self.stats.ok,
            Err(FrameError::Crc) => &mut self.stats.bad_crc,
            Err(FrameError::Cobs) => &mut self.stats.bad_cobs,
            Err(FrameError::TooShort) => &mut self.stats.too_short,
            Err(FrameError::TooLong) => &mut self.stats.too_long,
            Err(FrameError::Payload | FrameError::Encode) => &mut self.stats.bad_payload,
        };
        *counter = counter.saturating_add(1);
        Some(result)
    }

    fn check<M: DeserializeOwned>(encoded: &mut [u8]) -> Result<Frame<M>, FrameError> {
        let n = cobs::decode_in_place(encoded).map_err(|_| FrameError::Cobs)?;
        let raw = encoded.get(..n).ok_or(FrameError::Cobs)?;
        if raw.len() < SEQ_LEN + CRC_LEN {
            return Err(FrameError::TooShort);
        }
        if raw.len() > MAX_RAW_FRAME {
            return Err(FrameError::TooLong);
        }
        let (body, crc_bytes) = raw.split_at(raw.len() - CRC_LEN);
        let crc = u32::from_le_bytes([crc_bytes[0], crc_bytes[1], crc_bytes[2], crc_bytes[3]]);
        if CRC.checksum(body) != crc {
            return Err(FrameError::Crc);
        }
        let seq = u16::from_le_bytes([body[0], body[1]]);
        let (msg, rest) = postcard::take_from_bytes::<M>(&body[SEQ_LEN..]).map_err(|_| FrameError::Payload)?;
        // Trailing bytes mean the sender's schema differs from ours.
        if !rest.is_empty() {
            return Err(FrameError::Payload);
        }
        Ok(Frame { seq, msg })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::collection::vec as pvec;
    use proptest::prelude::*;
    use std::vec::Vec;

    /// A message type of the tests' own: framing is generic, so its tests need no wire message.
    #[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
    enum HostMsg {
        GetStatus,
        Start,
        Word(u32),
        Bytes { first: u16, data: heapless::Vec<u8, 64> },
    }

    mod arb {
        use super::*;

        pub fn host_msg() -> impl Strategy<Value = HostMsg> {
            prop_oneof![
                Just(HostMsg::GetStatus),
                Just(HostMsg::Start),
                any::<u32>().prop_map(HostMsg::Word),
                (any::<u16>(), pvec(any::<u8>(), 0..=64)).prop_map(|(first, bytes)| HostMsg::Bytes {
                    first,
                    data: bytes.into_iter().collect(),
                }),
            ]
        }
    }

    fn encoded(seq: u16, m: &HostMsg) -> Vec<u8> {
        let mut out = [0u8; MAX_WIRE_FRAME];
        let n = encode(seq, m, &mut out).unwrap();
        out[..n].to_vec()
    }

    /// Feed `bytes` in chunks of the given sizes (cycled); collect every decoder verdict.
    fn decode_all(dec: &mut FrameDecoder, bytes: &[u8], chunks: &[usize]) -> Vec<Result<Frame<HostMsg>, FrameError>> {
        let mut out = Vec::new();
        let mut pos = 0;
        let mut i = 0;
        while pos < bytes.len() {
            let n = chunks.get(i % chunks.len().max(1)).copied().unwrap_or(1).max(1);
            for &b in &bytes[pos..(pos + n).min(bytes.len())] {
                if let Some(r) = dec.push::<HostMsg>(b) {
                    out.push(r);
                }
            }
            pos += n;
            i += 1;
        }
        out
    }

    #[test]
    fn the_largest_payload_encodes_and_decodes() {
        let m = HostMsg::Bytes {
            first: u16::MAX,
            data: (0..64u8).map(|b| b | 1).collect(),
        };
        let f = encoded(7, &m);
        assert!(f.len() <= MAX_WIRE_FRAME);
        assert_eq!(
            decode_all(&mut FrameDecoder::new(), &f, &[1]),
            std::vec![Ok(Frame { seq: 7, msg: m })]
        );
    }

    #[test]
    fn encode_refuses_a_too_small_buffer() {
        let mut out = [0u8; 4];
        assert_eq!(encode(0, &HostMsg::GetStatus, &mut out), Err(FrameError::Encode));
    }

    #[test]
    fn oversize_input_is_rejected_not_buffered() {
        let mut dec = FrameDecoder::new();
        let junk = std::vec![0x55u8; 10 * MAX_WIRE_FRAME];
        assert!(junk.iter().all(|&b| dec.push::<HostMsg>(b).is_none()));
        assert_eq!(dec.push::<HostMsg>(0), Some(Err(FrameError::TooLong)));
        assert_eq!(dec.stats().too_long, 1);
        // And the next frame is decoded normally.
        let f = encoded(3, &HostMsg::Start);
        assert_eq!(
            decode_all(&mut dec, &f, &[5]),
            std::vec![Ok(Frame {
                seq: 3,
                msg: HostMsg::Start
            })]
        );
    }

    #[test]
    fn a_frame_of_another_schema_is_a_payload_error() {
        // A valid COBS+CRC frame whose payload is not a test message (variant index 200).
        let mut raw = std::vec![1u8, 0, 200, 1];
        let crc = CRC.checksum(&raw);
        raw.extend_from_slice(&crc.to_le_bytes());
        let mut out = [0u8; MAX_WIRE_FRAME];
        let n = cobs::try_encode(&raw, &mut out).unwrap();
        let mut bytes = out[..n].to_vec();
        bytes.push(0);
        let mut dec = FrameDecoder::new();
        assert_eq!(decode_all(&mut dec, &bytes, &[1]), std::vec![Err(FrameError::Payload)]);
        assert_eq!(dec.stats().bad_payload, 1);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        /// Concatenated frames, fed in arbitrary chunks, come out in order and intact.
        #[test]
        fn concatenated_frames_in_any_chunking(msgs in pvec(arb::host_msg(), 1..8), chunks in pvec(1usize..64, 1..8)) {
            let mut bytes = Vec::new();
            for (i, m) in msgs.iter().enumerate() {
                bytes.extend(encoded(i as u16, m));
            }
            let got = decode_all(&mut FrameDecoder::new(), &bytes, &chunks);
            let want: Vec<_> = msgs.iter().enumerate().map(|(i, m)| Ok(Frame { seq: i as u16, msg: m.clone() })).collect();
            prop_assert_eq!(got, want);
        }

        /// Arbitrary bytes never panic, and every frame accepted from them has a correct CRC
        /// (it re-encodes to exactly the bytes it came from).
        #[test]
        fn arbitrary_bytes_never_panic_and_accept_only_checked_frames(bytes in pvec(any::<u8>(), 0..2048)) {
            let mut dec = FrameDecoder::new();
            let mut start = 0;
            for (i, &b) in bytes.iter().enumerate() {
                if let Some(Ok(f)) = dec.push::<HostMsg>(b) {
                    let again = encoded(f.seq, &f.msg);
                    prop_assert_eq!(&again[..], &bytes[start..=i]);
                }
                if b == 0 { start = i + 1; }
            }
            prop_assert!(dec.stats().ok + dec.stats().bad() <= bytes.iter().filter(|&&b| b == 0).count() as u32);
        }

        /// Garbage, then a valid frame: the frame is recovered (the garbage costs at most one
        /// dropped candidate, the one the frame's delimiter closes, if the garbage has no 0x00 end).
        #[test]
        fn valid_frames_after_garbage_are_recovered(garbage in pvec(any::<u8>(), 0..600), m in arb::host_msg()) {
            let mut bytes = garbage.clone();
            bytes.push(0); // the sender's resync delimiter before a frame
            bytes.extend(encoded(42, &m));
            let got = decode_all(&mut FrameDecoder::new(), &bytes, &[17]);
            prop_assert_eq!(got.last().cloned(), Some(Ok(Frame { seq: 42, msg: m })));
        }

        /// A single flipped bit anywhere in a frame is never accepted as a (different) message.
        #[test]
        fn flipped_bits_are_never_accepted(m in arb::host_msg(), pos in any::<proptest::sample::Index>(), bit in 0u8..8) {
            let mut f = encoded(5, &m);
            let body = f.len() - 1; // keep the delimiter: flipping it is the truncation case below
            let i = pos.index(body);
            f[i] ^= 1 << bit;
            let got = decode_all(&mut FrameDecoder::new(), &f, &[3]);
            for r in &got {
                prop_assert!(r.is_err(), "corrupted frame accepted: {:?}", r);
            }
        }

        /// Truncated frames are rejected, and the next complete frame still decodes.
        #[test]
        fn truncated_frames_are_rejected(m in arb::host_msg(), cut in any::<proptest::sample::Index>(), next in arb::host_msg()) {
            let f = encoded(1, &m);
            let keep = cut.index(f.len() - 1);
            let mut bytes = f[..keep].to_vec();
            bytes.push(0);
            bytes.extend(encoded(2, &next));
            let got = decode_all(&mut FrameDecoder::new(), &bytes, &[7]);
            prop_assert_eq!(got.last().cloned(), Some(Ok(Frame { seq: 2, msg: next })));
            for r in &got[..got.len() - 1] {
                prop_assert!(r.is_err());
            }
        }
    }
}
