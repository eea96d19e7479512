//! The scan journal, `OUTDIR/journal`: every measurement appended as it arrives and synced to disk
//! before the firmware is told it may forget it, so a crash, a kill or an unplugged cable loses
//! nothing that was acknowledged, and `--resume` continues with the directions not in it.
//!
//! Format (text, one record per line, fields separated by single spaces):
//!
//! ```text
//! gonio-journal 1 plan=<FNV-1a 64 of the plan file bytes, 16 hex> directions=<N>
//! m <index> <steps light> <steps detector> <steps tilt> <steps azimuth> <exposure_us> <timestamp_us> <session> <counts, comma-separated> <FNV-1a 32 of everything before it on the line, 8 hex>
//! ```
//!
//! `index` is the direction's index in the plan file; `session` counts connections (timestamps are
//! per firmware boot). A last line without its newline or with a wrong checksum is a write torn by
//! a crash: it is cut off on resume (that direction is measured again). A damaged line before the
//! last is an error: the file was changed by something else.

use gonio_shared::msg::Measurement;
use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

pub const FILE_NAME: &str = "journal";

#[derive(Debug, thiserror::Error)]
pub enum JournalError {
    #[error("journal {path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("journal {path}: line {line} is damaged")]
    Damaged { path: String, line: usize },
    #[error("journal {path} belongs to another plan (plan hash or size differs)")]
    OtherPlan { path: String },
    #[error("journal {path} is not a gonio journal")]
    NotAJournal { path: String },
    #[error("journal {path}: direction {index} is outside the {total}-direction plan")]
    OutOfPlan { path: String, index: u32, total: u32 },
}

/// One journaled reading.
#[derive(Clone, Debug, PartialEq)]
pub struct Record {
    pub index: u32,
    pub steps: [i32; 4],
    pub exposure_us: u32,
    pub timestamp_us: u64,
    pub session: u32,
    pub counts: Vec<u32>,
}

pub struct Journal {
    path: PathBuf,
    file: File,
    records: BTreeMap<u32, Record>,
    total: u32,
    pub session: u32,
}

pub fn fnv64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

fn fnv32(bytes: &[u8]) -> u32 {
    bytes
        .iter()
        .fold(0x811c_9dc5u32, |h, &b| (h ^ u32::from(b)).wrapping_mul(0x0100_0193))
}

fn header(plan_hash: u64, total: u32) -> String {
    format!("gonio-journal 1 plan={plan_hash:016x} directions={total}\n")
}

impl Journal {
    pub fn path_in(dir: &Path) -> PathBuf {
        dir.join(FILE_NAME)
    }

    /// Start a new journal (refuses to overwrite one).
    pub fn create(dir: &Path, plan_hash: u64, total: u32) -> Result<Self, JournalError> {
        let path = Self::path_in(dir);
        let io = |source| JournalError::Io {
            path: path.display().to_string(),
            source,
        };
        let mut file = OpenOptions::new()
            .create_new(true)
            .append(true)
            .open(&path)
            .map_err(io)?;
        file.write_all(header(plan_hash, total).as_bytes()).map_err(io)?;
        file.sync_all().map_err(io)?;
        // The new name must be on disk before any reading is acknowledged as synced.
        crate::fsio::sync_dir(dir).map_err(io)?;
        // The folder's own entry too (a scan creates the folder just before); best effort, as a
        // parent may be searchable without being readable.
        let _ = crate::fsio::sync_dir(crate::fsio::parent_dir(dir));
        Ok(Self {
            path,
            file,
            records: BTreeMap::new(),
            total,
            session: 0,
        })
    }

    /// Reopen a journal to continue its plan; cuts off a torn last line.
    pub fn resume(dir: &Path, plan_hash: u64, total: u32) -> Result<Self, JournalError> {
        let path = Self::path_in(dir);
        let p = path.display().to_string();
        let io = |source| JournalError::Io {
            path: p.clone(),
            source,
        };
        let bytes = std::fs::read(&path).map_err(io)?;
        let want = header(plan_hash, total);
        if !bytes.starts_with(b"gonio-journal ") {
            return Err(JournalError::NotAJournal { path: p });
        }
        if !bytes.starts_with(want.as_bytes()) {
            return Err(JournalError::OtherPlan { path: p });
        }
        let mut records = BTreeMap::new();
        let mut good_len = want.len();
        let mut session = 0;
        let body = bytes.get(want.len()..).unwrap_or(&[]);
        let lines: Vec<&[u8]> = body.split_inclusive(|&b| b == b'\n').collect();
        for (k, line) in lines.iter().enumerate() {
            let last = k + 1 == lines.len();
            match parse_record(line) {
                Some(r) => {
                    if r.index >= total {
                        return Err(JournalError::OutOfPlan {
                            path: p,
                            index: r.index,
                            total,
                        });
                    }
                    session = session.max(r.session + 1);
                    records.entry(r.index).or_insert(r);
                    good_len += line.len();
                }
                None if last => break,
                None => return Err(JournalError::Damaged { path: p, line: k + 2 }),
            }
        }
        let file = OpenOptions::new().write(true).open(&path).map_err(io)?;
        file.set_len(good_len as u64).map_err(io)?;
        drop(file);
        let file = OpenOptions::new().append(true).open(&path).map_err(io)?;
        Ok(Self {
            path,
            file,
            records,
            total,
            session,
        })
    }

    pub fn total(&self) -> u32 {
        self.total
    }

    pub fn records(&self) -> &BTreeMap<u32, Record> {
        &self.records
    }

    /// Plan indices not yet measured, in plan order.
    pub fn remaining(&self) -> Vec<u32> {
        self.remaining_below(self.total)
    }

    /// Plan indices below `limit` not yet measured, in plan order (a progressive scan measures
    /// its plan one level, a prefix, at a time).
    pub fn remaining_below(&self, limit: u32) -> Vec<u32> {
        (0..self.total.min(limit))
            .filter(|i| !self.records.contains_key(i))
            .collect()
    }

    /// Append one reading taken at plan direction `index` (not yet synced).
    pub fn append(&mut self, index: u32, m: &Measurement) -> Result<(), JournalError> {
        let r = Record {
            index,
            steps: m.steps,
            exposure_us: m.exposure_us,
            timestamp_us: m.timestamp_us,
            session: self.session,
            counts: m.counts.to_vec(),
        };
        let line = format_record(&r);
        self.file
            .write_all(line.as_bytes())
            .map_err(|source| JournalError::Io {
                path: self.path.display().to_string(),
                source,
            })?;
        self.records.entry(index).or_insert(r);
        Ok(())
    }

    pub fn sync(&mut self) -> Result<(), JournalError> {
        self.file.sync_data().map_err(|source| JournalError::Io {
            path: self.path.display().to_string(),
            source,
        })
    }
}

fn format_record(r: &Record) -> String {
    let counts: Vec<String> = r.counts.iter().map(u32::to_string).collect();
    let body = format!(
        "m {} {} {} {} {} {} {} {} {}",
        r.index,
        r.steps[0],
        r.steps[1],
        r.steps[2],
        r.steps[3],
        r.exposure_us,
        r.timestamp_us,
        r.session,
        counts.join(",")
    );
    format!("{body} {:08x}\n", fnv32(body.as_bytes()))
}

fn parse_record(line: &[u8]) -> Option<Record> {
    let text = std::str::from_utf8(line).ok()?.strip_suffix('\n')?;
    let (body, sum) = text.rsplit_once(' ')?;
    if u32::from_str_radix(sum, 16).ok()? != fnv32(body.as_bytes()) || sum.len() != 8 {
        return None;
    }
    let f: Vec<&str> = body.split(' ').collect();
    if f.len() != 10 || f.first() != Some(&"m") {
        return None;
    }
    let num = |i: usize| f.get(i).copied().unwrap_or("");
    let counts = if num(9).is_empty() {
        Vec::new()
    } else {
        num(9)
            .split(',')
            .map(|c| c.parse().ok())
            .collect::<Option<Vec<u32>>>()?
    };
    Some(Record {
        index: num(1).parse().ok()?,
        steps: [
            num(2).parse().ok()?,
            num(3).parse().ok()?,
            num(4).parse().ok()?,
            num(5).parse().ok()?,
        ],
        exposure_us: num(6).parse().ok()?,
        timestamp_us: num(7).parse().ok()?,
        session: num(8).parse().ok()?,
        counts,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(seq: u32) -> Measurement {
        Measurement {
            seq,
            index: seq,
            steps: [1, -2, 3, 0],
            counts: heapless::Vec::from_slice(&[10, 20, 30]).unwrap(),
            exposure_us: 1000,
            timestamp_us: 42 + u64::from(seq),
        }
    }

    #[test]
    fn records_survive_a_reopen_and_a_torn_last_line_is_cut() {
        let dir = tempfile::tempdir().unwrap();
        let mut j = Journal::create(dir.path(), 7, 5).unwrap();
        j.append(0, &m(0)).unwrap();
        j.append(3, &m(1)).unwrap();
        j.sync().unwrap();
        drop(j);
        // A crash in the middle of the next line.
        let path = Journal::path_in(dir.path());
        let mut f = OpenOptions::new().append(true).open(&path).unwrap();
        f.write_all(b"m 4 1 2 3").unwrap();
        drop(f);
        let j = Journal::resume(dir.path(), 7, 5).unwrap();
        assert_eq!(j.remaining(), vec![1, 2, 4]);
        assert_eq!(j.records()[&3].counts, vec![10, 20, 30]);
        assert_eq!(j.session, 1);
        assert!(!std::fs::read_to_string(&path).unwrap().contains("m 4 1 2 3"));
        assert!(matches!(
            Journal::resume(dir.path(), 8, 5),
            Err(JournalError::OtherPlan { .. })
        ));
        assert!(
            Journal::create(dir.path(), 7, 5).is_err(),
            "must not overwrite a journal"
        );
    }

    #[test]
    fn a_damaged_middle_line_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let mut j = Journal::create(dir.path(), 1, 5).unwrap();
        j.append(0, &m(0)).unwrap();
        j.append(1, &m(1)).unwrap();
        drop(j);
        let path = Journal::path_in(dir.path());
        let text = std::fs::read_to_string(&path).unwrap().replacen("m 0 1", "m 0 2", 1);
        std::fs::write(&path, text).unwrap();
        assert!(matches!(
            Journal::resume(dir.path(), 1, 5),
            Err(JournalError::Damaged { line: 2, .. })
        ));
    }
}
