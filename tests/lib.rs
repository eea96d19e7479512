//! Cross-crate tests of gonio live in this package's test targets (see Cargo.toml); this library
//! holds what several of them share.

/// Encode `msg` as one wire frame (the bytes a sender writes, delimiter included).
pub fn frame_bytes<M: serde::Serialize>(seq: u16, msg: &M) -> Vec<u8> {
    let mut out = [0u8; gonio_shared::frame::MAX_WIRE_FRAME];
    let n = gonio_shared::frame::encode(seq, msg, &mut out).expect("message fits in a frame");
    out[..n].to_vec()
}
