//! `gonio-lab tradeoff` as a user meets it: bad input gives a clear error, a non-zero exit and no
//! output folder.

use std::path::Path;
use std::process::{Command, Output};

fn lab(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gonio-lab"))
        .args(args)
        .current_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join(".."))
        .output()
        .expect("run gonio-lab")
}

#[test]
fn bad_tradeoff_inputs_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("tradeoff");
    for levels in ["4x4,6x6", "8x8,4x4", "3"] {
        let out = lab(&["tradeoff", "--levels", levels, "-o", out_dir.to_str().unwrap()]);
        assert!(!out.status.success(), "{levels}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("panicked") && err.contains("--levels"), "{err}");
        assert!(!out_dir.exists());
    }
    let out = lab(&[
        "tradeoff",
        "--material",
        "nbrdf:no-such",
        "-o",
        out_dir.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    assert!(!out_dir.exists());
}
