//! Arbitrary bytes into both frame decoders (host -> firmware and firmware -> host messages).
//! Invariants: no panic; every accepted frame re-encodes to exactly the bytes it was decoded from
//! (so nothing with a wrong CRC or a non-canonical payload is ever accepted).
#![no_main]

use gonio_shared::frame::{encode, FrameDecoder, MAX_WIRE_FRAME};
use gonio_shared::msg::{DeviceMsg, HostMsg};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut host = FrameDecoder::new();
    let mut device = FrameDecoder::new();
    let mut start = 0;
    for (i, &b) in data.iter().enumerate() {
        let mut out = [0u8; MAX_WIRE_FRAME];
        if let Some(Ok(f)) = host.push::<HostMsg>(b) {
            let n = encode(f.seq, &f.msg, &mut out).expect("an accepted frame re-encodes");
            assert_eq!(&out[..n], &data[start..=i]);
        }
        if let Some(Ok(f)) = device.push::<DeviceMsg>(b) {
            let n = encode(f.seq, &f.msg, &mut out).expect("an accepted frame re-encodes");
            assert_eq!(&out[..n], &data[start..=i]);
        }
        if b == 0 {
            start = i + 1;
        }
    }
});
