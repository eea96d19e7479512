//! `measurements.csv`: one row per plan direction measured, from the journal.

use super::reached;
use crate::journal::Journal;
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::kinematics::Kinematics;
use gonio_shared::msg::Direction;
use std::path::Path;

/// The columns before the per-channel counts.
const COLUMNS: [&str; 16] = [
    "index",
    "theta_i_deg",
    "phi_i_deg",
    "theta_o_deg",
    "phi_o_deg",
    "reached_theta_i_deg",
    "reached_phi_i_deg",
    "reached_theta_o_deg",
    "reached_phi_o_deg",
    "steps_light",
    "steps_detector",
    "steps_tilt",
    "steps_azimuth",
    "exposure_us",
    "timestamp_us",
    "session",
];

/// `measurements.csv`, written atomically: one row per plan direction measured, by index.
///
/// Columns: `index`, the requested `theta_i,phi_i,theta_o,phi_o` (degrees), the pose reached (the
/// same four, from forward kinematics of the reported step positions, see [`reached`]), the four step
/// positions, `exposure_us`, `timestamp_us` (device clock of that session), `session`, and one
/// `count_K` column per detector channel.
pub fn write_csv(
    path: &Path,
    cfg: &InstrumentConfig<f64>,
    plan: &[Direction],
    journal: &Journal,
) -> std::io::Result<()> {
    let kin = Kinematics::new(*cfg).map_err(|e| std::io::Error::other(e.to_string()))?;
    let channels = journal.records().values().map(|r| r.counts.len()).max().unwrap_or(0);
    let mut w = csv::WriterBuilder::new()
        .terminator(csv::Terminator::Any(b'\n'))
        .from_writer(Vec::new());
    let header = COLUMNS
        .iter()
        .map(|c| c.to_string())
        .chain((0..channels).map(|k| format!("count_{k}")));
    w.write_record(header)?;
    let deg = |a: f32| format!("{:.6}", f64::from(a).to_degrees());
    for (index, r) in journal.records() {
        let Some(d) = plan.get(*index as usize) else { continue };
        let reached = reached(&kin, &r.steps).map(|a| format!("{:.6}", a.to_degrees()));
        let row = [
            index.to_string(),
            deg(d.theta_i),
            deg(d.phi_i),
            deg(d.theta_o),
            deg(d.phi_o),
        ]
        .into_iter()
        .chain(reached)
        .chain(r.steps.iter().map(i32::to_string))
        .chain([
            r.exposure_us.to_string(),
            r.timestamp_us.to_string(),
            r.session.to_string(),
        ])
        .chain((0..channels).map(|k| r.counts.get(k).map_or(String::new(), u32::to_string)));
        w.write_record(row)?;
    }
    let bytes = w.into_inner().map_err(|e| e.into_error())?;
    crate::fsio::write_bytes_atomically(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_shared::msg::Measurement;

    /// The rows are the hand-written format of before: plain numbers, `\n` line ends, an empty
    /// cell for a channel a reading lacks.
    #[test]
    fn rows_have_the_documented_columns_and_plain_cells() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = crate::instrument::load_or_default(None).unwrap();
        let plan = [Direction {
            theta_i: 0.5,
            phi_i: 0.0,
            theta_o: 0.25,
            phi_o: 3.0,
        }; 3];
        let mut journal = Journal::create(dir.path(), 1, 3).unwrap();
        for (index, counts) in [(0u32, &[7u32, 8][..]), (2, &[9][..])] {
            let m = Measurement {
                seq: index,
                index,
                steps: [1, -2, 3, 0],
                counts: heapless::Vec::from_slice(counts).unwrap(),
                exposure_us: 1000,
                timestamp_us: 42,
            };
            journal.append(index, &m).unwrap();
        }
        let path = dir.path().join("m.csv");
        write_csv(&path, &cfg, &plan, &journal).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.split('\n').collect();
        assert_eq!(lines.len(), 4, "{text}");
        assert_eq!(lines[0], format!("{},count_0,count_1", COLUMNS.join(",")));
        assert!(
            lines[1].starts_with("0,28.647890,0.000000,14.323945,171.887339,"),
            "{}",
            lines[1]
        );
        assert!(lines[1].ends_with(",1,-2,3,0,1000,42,0,7,8"), "{}", lines[1]);
        assert!(lines[2].ends_with(",1,-2,3,0,1000,42,0,9,"), "{}", lines[2]);
        assert_eq!(lines[3], "");
    }
}
