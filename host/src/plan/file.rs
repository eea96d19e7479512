//! The plan file (`PLAN.bin`): the plan exactly as it goes down the wire, so the firmware's own
//! decoder could read it. It is a sequence of frames (`gonio_shared::frame`), one
//! `HostMsg::Plan` chunk after another (`first_index` 0, 8, 16, ...; frame sequence numbers 0, 1, 2, ...),
//! closed by one `HostMsg::PlanEnd { total }`. Nothing else, nothing after.
//!
//! A live scan renumbers the frames for its own link session; the file only fixes the directions and
//! their order.

use gonio_shared::frame::{self, FrameDecoder, MAX_WIRE_FRAME};
use gonio_shared::msg::{caps::CHUNK_DIRECTIONS, Direction, HostMsg, PlanChunk};
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum PlanFileError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("plan file: frame {frame} is damaged ({reason:?})")]
    BadFrame { frame: usize, reason: frame::FrameError },
    #[error("plan file: frame {frame} is not a plan chunk or plan end")]
    NotAPlan { frame: usize },
    #[error("plan file: chunk at frame {frame} starts at direction {found}, expected {expected}")]
    OutOfOrder { frame: usize, expected: u32, found: u32 },
    #[error("plan file: it says {total} directions but holds {found}")]
    WrongTotal { total: u32, found: u32 },
    #[error("plan file: it ends without a plan-end frame (truncated?)")]
    Truncated,
    #[error("plan file: bytes after the plan-end frame")]
    TrailingData,
    #[error("plan file: direction {index} is not finite")]
    NotFinite { index: usize },
    #[error("plan has {0} directions, more than the wire's u32 index can count")]
    TooLong(usize),
}

/// Encode `directions` as the plan file's bytes.
pub fn encode_plan(directions: &[Direction]) -> Result<Vec<u8>, PlanFileError> {
    if let Some(index) = directions.iter().position(|d| !direction_is_finite(d)) {
        return Err(PlanFileError::NotFinite { index });
    }
    let total = u32::try_from(directions.len()).map_err(|_| PlanFileError::TooLong(directions.len()))?;
    let mut out = Vec::with_capacity(directions.len() / CHUNK_DIRECTIONS * 140 + MAX_WIRE_FRAME);
    let mut buf = [0u8; MAX_WIRE_FRAME];
    let mut seq: u16 = 0;
    let mut push = |msg: &HostMsg, out: &mut Vec<u8>| {
        // A chunk of CHUNK_DIRECTIONS directions always fits a frame (the wire's size test checks
        // the largest message), so encoding cannot fail here.
        let n = frame::encode(seq, msg, &mut buf).expect("a plan chunk always fits a wire frame");
        out.extend_from_slice(&buf[..n]);
        seq = seq.wrapping_add(1);
    };
    for (k, chunk) in directions.chunks(CHUNK_DIRECTIONS).enumerate() {
        let msg = HostMsg::Plan(PlanChunk {
            first_index: (k * CHUNK_DIRECTIONS) as u32,
            directions: heapless::Vec::from_slice(chunk).expect("chunks() yields at most CHUNK_DIRECTIONS"),
        });
        push(&msg, &mut out);
    }
    push(&HostMsg::PlanEnd { total }, &mut out);
    Ok(out)
}

/// Decode and check a plan file's bytes: every frame intact, chunks consecutive from 0, the total
/// right, nothing after the end.
pub fn decode_plan(bytes: &[u8]) -> Result<Vec<Direction>, PlanFileError> {
    let mut decoder = FrameDecoder::new();
    let mut directions = Vec::new();
    let mut frames = 0usize;
    let mut ended = false;
    for &byte in bytes {
        if ended {
            if byte != 0 {
                return Err(PlanFileError::TrailingData);
            }
            continue;
        }
        let Some(result) = decoder.push::<HostMsg>(byte) else {
            continue;
        };
        let frame = result.map_err(|reason| PlanFileError::BadFrame { frame: frames, reason })?;
        match frame.msg {
            HostMsg::Plan(chunk) => {
                let expected = directions.len() as u32;
                if chunk.first_index != expected {
                    return Err(PlanFileError::OutOfOrder {
                        frame: frames,
                        expected,
                        found: chunk.first_index,
                    });
                }
                directions.extend_from_slice(&chunk.directions);
            }
            HostMsg::PlanEnd { total } => {
                if total as usize != directions.len() {
                    return Err(PlanFileError::WrongTotal {
                        total,
                        found: directions.len() as u32,
                    });
                }
                ended = true;
            }
            _ => return Err(PlanFileError::NotAPlan { frame: frames }),
        }
        frames += 1;
    }
    if !ended {
        return Err(PlanFileError::Truncated);
    }
    if let Some(index) = directions.iter().position(|d| !direction_is_finite(d)) {
        return Err(PlanFileError::NotFinite { index });
    }
    Ok(directions)
}

/// Write a plan file atomically (temporary name, then rename).
pub fn write_plan_file(path: &Path, directions: &[Direction]) -> Result<(), PlanFileError> {
    let bytes = encode_plan(directions)?;
    crate::fsio::write_bytes_atomically(path, &bytes).map_err(|source| PlanFileError::Io {
        path: path.display().to_string(),
        source,
    })
}

pub fn read_plan_file(path: &Path) -> Result<Vec<Direction>, PlanFileError> {
    let bytes = std::fs::read(path).map_err(|source| PlanFileError::Io {
        path: path.display().to_string(),
        source,
    })?;
    decode_plan(&bytes)
}

fn direction_is_finite(d: &Direction) -> bool {
    [d.theta_i, d.phi_i, d.theta_o, d.phi_o].iter().all(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn direction(k: usize) -> Direction {
        let t = k as f32;
        Direction {
            theta_i: 0.01 * t,
            phi_i: 0.0,
            theta_o: 0.02 * t,
            phi_o: -0.03 * t,
        }
    }

    fn plan(n: usize) -> Vec<Direction> {
        (0..n).map(direction).collect()
    }

    #[test]
    fn round_trips_at_chunk_boundaries_and_empty() {
        for n in [0, 1, CHUNK_DIRECTIONS - 1, CHUNK_DIRECTIONS, CHUNK_DIRECTIONS + 1, 1000] {
            let bytes = encode_plan(&plan(n)).unwrap();
            assert_eq!(decode_plan(&bytes).unwrap(), plan(n), "n = {n}");
        }
    }

    #[test]
    fn refuses_truncated_reordered_trailing_and_non_finite_plans() {
        let bytes = encode_plan(&plan(20)).unwrap();
        // Cut inside the last frame (it never closes) and after the last chunk (no plan end).
        assert!(matches!(
            decode_plan(&bytes[..bytes.len() - 3]),
            Err(PlanFileError::Truncated)
        ));
        let frames: Vec<&[u8]> = bytes.split_inclusive(|&b| b == 0).collect();
        assert_eq!(frames.len(), 4, "three chunks and the end");
        assert!(matches!(
            decode_plan(&frames[..3].concat()),
            Err(PlanFileError::Truncated)
        ));
        // Chunks swapped.
        let swapped = [frames[1], frames[0], frames[2], frames[3]].concat();
        assert!(matches!(
            decode_plan(&swapped),
            Err(PlanFileError::OutOfOrder {
                frame: 0,
                expected: 0,
                found: 8
            })
        ));
        // A chunk missing: the total no longer matches.
        let missing = [frames[0], frames[1], frames[3]].concat();
        assert!(matches!(
            decode_plan(&missing),
            Err(PlanFileError::WrongTotal { total: 20, found: 16 })
        ));
        let mut trailing = bytes.clone();
        trailing.extend_from_slice(frames[0]);
        assert!(matches!(decode_plan(&trailing), Err(PlanFileError::TrailingData)));
        let mut bad = plan(3);
        bad[2].theta_o = f32::NAN;
        assert!(matches!(encode_plan(&bad), Err(PlanFileError::NotFinite { index: 2 })));
        assert!(matches!(
            decode_plan(b"not a plan at all\0"),
            Err(PlanFileError::BadFrame { .. })
        ));
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]
        /// A flipped byte is caught by the CRC (or COBS) and never decodes to a different plan.
        #[test]
        fn a_flipped_byte_never_passes_as_another_plan(n in 1usize..40, at in any::<prop::sample::Index>(), flip in 1u8..=255) {
            let mut bytes = encode_plan(&plan(n)).unwrap();
            let i = at.index(bytes.len());
            bytes[i] ^= flip;
            if let Ok(decoded) = decode_plan(&bytes) {
                prop_assert_eq!(decoded, plan(n));
            }
        }
    }

    #[test]
    fn write_then_read_through_a_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("plan.bin");
        write_plan_file(&path, &plan(33)).unwrap();
        assert_eq!(read_plan_file(&path).unwrap(), plan(33));
        let e = read_plan_file(&dir.path().join("missing.bin")).unwrap_err();
        assert!(e.to_string().contains("missing.bin"), "{e}");
    }
}
