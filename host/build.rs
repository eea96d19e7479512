//! Sets `GONIO_VERSION`: the package version, plus `git describe --always` when git is at hand.

use std::path::PathBuf;
use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    let text = String::from_utf8(out.stdout).ok()?;
    (out.status.success() && !text.trim().is_empty()).then(|| text.trim().to_string())
}

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let version = env!("CARGO_PKG_VERSION");
    let describe = git(&["describe", "--always", "--tags"]);
    if describe.is_some() {
        // Rebuild when HEAD moves: HEAD itself, the branch it names and packed refs.
        // A path that does not exist would rerun this script on every build: watch only files.
        let mut watch = Vec::new();
        if let Some(dir) = git(&["rev-parse", "--git-dir"]) {
            watch.push(PathBuf::from(dir).join("HEAD"));
        }
        if let (Some(common), Some(head)) = (
            git(&["rev-parse", "--git-common-dir"]),
            git(&["rev-parse", "--symbolic-full-name", "HEAD"]),
        ) {
            let common = PathBuf::from(common);
            watch.push(common.join(&head));
            watch.push(common.join("packed-refs"));
        }
        for path in watch.iter().filter(|p| p.is_file()) {
            println!("cargo:rerun-if-changed={}", path.display());
        }
    }
    match describe {
        Some(d) => println!("cargo:rustc-env=GONIO_VERSION={version} ({d})"),
        None => println!("cargo:rustc-env=GONIO_VERSION={version}"),
    }
}
