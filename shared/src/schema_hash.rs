//! A compile-time hash of the postcard schema of the wire messages.
//!
//! Host and firmware exchange it in the handshake: if a message gains a field, changes a type or
//! reorders variants on one side only, the hashes differ and both refuse to talk. FNV-1a over a
//! canonical walk of `postcard_schema::NamedType` (names included: renaming is a change too).

use postcard_schema::schema::{DataModelType as Dmt, DataModelVariant as Dmv, NamedType, NamedValue};

const FNV_OFFSET: u32 = 0x811c_9dc5;
const FNV_PRIME: u32 = 0x0100_0193;

const fn byte(h: u32, b: u8) -> u32 {
    (h ^ b as u32).wrapping_mul(FNV_PRIME)
}

const fn bytes(mut h: u32, s: &[u8]) -> u32 {
    // Length first so ("ab","c") and ("a","bc") differ.
    h = byte(h, s.len() as u8);
    let mut i = 0;
    while i < s.len() {
        h = byte(h, s[i]);
        i += 1;
    }
    h
}

const fn types(mut h: u32, nts: &[&NamedType]) -> u32 {
    h = byte(h, nts.len() as u8);
    let mut i = 0;
    while i < nts.len() {
        h = named_type(h, nts[i]);
        i += 1;
    }
    h
}

const fn values(mut h: u32, nvs: &[&NamedValue]) -> u32 {
    h = byte(h, nvs.len() as u8);
    let mut i = 0;
    while i < nvs.len() {
        h = bytes(h, nvs[i].name.as_bytes());
        h = named_type(h, nvs[i].ty);
        i += 1;
    }
    h
}

const fn named_type(h: u32, nt: &NamedType) -> u32 {
    data_model(bytes(h, nt.name.as_bytes()), nt.ty)
}

const fn data_model(h: u32, ty: &Dmt) -> u32 {
    match ty {
        Dmt::Bool => byte(h, 1),
        Dmt::I8 => byte(h, 2),
        Dmt::U8 => byte(h, 3),
        Dmt::I16 => byte(h, 4),
        Dmt::I32 => byte(h, 5),
        Dmt::I64 => byte(h, 6),
        Dmt::I128 => byte(h, 7),
        Dmt::U16 => byte(h, 8),
        Dmt::U32 => byte(h, 9),
        Dmt::U64 => byte(h, 10),
        Dmt::U128 => byte(h, 11),
        Dmt::Usize => byte(h, 12),
        Dmt::Isize => byte(h, 13),
        Dmt::F32 => byte(h, 14),
        Dmt::F64 => byte(h, 15),
        Dmt::Char => byte(h, 16),
        Dmt::String => byte(h, 17),
        Dmt::ByteArray => byte(h, 18),
        Dmt::Option(nt) => named_type(byte(h, 19), nt),
        Dmt::Unit => byte(h, 20),
        Dmt::UnitStruct => byte(h, 21),
        Dmt::NewtypeStruct(nt) => named_type(byte(h, 22), nt),
        Dmt::Seq(nt) => named_type(byte(h, 23), nt),
        Dmt::Tuple(nts) => types(byte(h, 24), nts),
        Dmt::TupleStruct(nts) => types(byte(h, 25), nts),
        Dmt::Map { key, val } => named_type(named_type(byte(h, 26), key), val),
        Dmt::Struct(nvs) => values(byte(h, 27), nvs),
        Dmt::Enum(vars) => {
            let mut h = byte(byte(h, 28), vars.len() as u8);
            let mut i = 0;
            while i < vars.len() {
                h = bytes(h, vars[i].name.as_bytes());
                h = match vars[i].ty {
                    Dmv::UnitVariant => byte(h, 1),
                    Dmv::NewtypeVariant(nt) => named_type(byte(h, 2), nt),
                    Dmv::TupleVariant(nts) => types(byte(h, 3), nts),
                    Dmv::StructVariant(nvs) => values(byte(h, 4), nvs),
                };
                i += 1;
            }
            h
        }
        Dmt::Schema => byte(h, 29),
    }
}

/// Hash of the host->device and device->host schemas together.
pub const fn schema_hash32(host: &NamedType, device: &NamedType) -> u32 {
    named_type(named_type(FNV_OFFSET, host), device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use postcard_schema::Schema;

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

    #[test]
    fn any_change_of_shape_changes_the_hash() {
        let a = schema_hash32(A::SCHEMA, A::SCHEMA);
        assert_eq!(a, schema_hash32(A::SCHEMA, A::SCHEMA));
        assert_ne!(a, schema_hash32(B::SCHEMA, A::SCHEMA), "field type");
        assert_ne!(a, schema_hash32(C::SCHEMA, A::SCHEMA), "field order");
        assert_ne!(
            schema_hash32(A::SCHEMA, B::SCHEMA),
            schema_hash32(B::SCHEMA, A::SCHEMA),
            "direction"
        );
    }
}
