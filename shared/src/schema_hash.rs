//! The compile-time hash of the wire schema that host and firmware compare in the handshake.
//!
//! postcard-schema's [`Key`] of the pair (host -> device, device -> host) message types, folded
//! to the 32 bits `Hello` carries: a field, type, variant or order change on one side only makes
//! the hashes differ, and both sides refuse to talk.

use postcard_schema::key::Key;
use postcard_schema::Schema;

/// The path the key is computed under (part of the hash, so a rename of it is a wire change).
const KEY_PATH: &str = "gonio/wire";

/// Hash of the host -> device schema `H` and the device -> host schema `D` together.
pub const fn schema_hash32<H: Schema, D: Schema>() -> u32 {
    let k = Key::for_path::<(H, D)>(KEY_PATH).to_bytes();
    u32::from_le_bytes([k[0] ^ k[4], k[1] ^ k[5], k[2] ^ k[6], k[3] ^ k[7]])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(serde::Serialize, Schema)]
    #[allow(dead_code)]
    struct A {
        x: u32,
        y: f32,
    }
    #[derive(serde::Serialize, Schema)]
    #[allow(dead_code)]
    struct B {
        x: u32,
        y: f64,
    }
    #[derive(serde::Serialize, Schema)]
    #[allow(dead_code)]
    struct C {
        y: f32,
        x: u32,
    }
    #[derive(serde::Serialize, Schema)]
    #[allow(dead_code)]
    struct D {
        x: u32,
        z: f32,
    }

    #[test]
    fn any_change_of_shape_changes_the_hash() {
        let a = schema_hash32::<A, A>();
        assert_eq!(a, schema_hash32::<A, A>());
        assert_ne!(a, schema_hash32::<B, A>(), "field type");
        assert_ne!(a, schema_hash32::<C, A>(), "field order");
        assert_ne!(a, schema_hash32::<D, A>(), "field name");
        assert_ne!(schema_hash32::<A, B>(), schema_hash32::<B, A>(), "direction");
    }
}
