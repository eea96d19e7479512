//! `gonio measure` as a user runs it: resume after the host is killed, a device that is killed and
//! comes back, a limit fault mid-scan, and bad inputs (one line, non-zero exit, nothing written).

mod common_link;

use common_link::*;
use gonio::sim::{model::SimModel, SimHandle};
use std::path::Path;
use std::process::{Child, Stdio};
use std::sync::Arc;

const N: usize = 60;

fn reference(fx: &Fixture) -> Vec<String> {
    let out = fx.path("reference");
    let o = fx.measure_sim(&fx.plan, &out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rows = csv_without_time(&out.join("measurements.csv"));
    assert_eq!(rows.len(), N);
    rows
}

/// Wait (a failure guard, not a measurement) until the journal holds at least `n` records.
fn sim_on_link(fx: &Fixture, speedup: f64) -> SimHandle {
    let model = SimModel::load(&fx.scene, fx.instrument_config(), 1).unwrap();
    SimHandle::spawn(Arc::new(model), speedup, Some(fx.path("port"))).unwrap()
}

fn measure_child(fx: &Fixture, out: &Path, extra: &[&str]) -> Child {
    let port = fx.path("port");
    gonio()
        .args([
            "measure",
            "--port",
            s(&port),
            "--plan",
            s(&fx.plan),
            "--instrument",
            s(&fx.instrument),
            "-o",
            s(out),
        ])
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

#[test]
fn host_killed_mid_scan_resumes_to_the_same_result() {
    let fx = Fixture::new(N, "");
    let want = reference(&fx);
    // A slow device, so the kill lands mid-scan.
    let sim = sim_on_link(&fx, 20.0);
    let out = fx.path("killed");
    let mut child = measure_child(&fx, &out, &[]);
    wait_for_records(&out, 10, &mut child);
    child.kill().unwrap();
    child.wait().unwrap();
    let before = journal_records(&out).len();
    assert!(before < N, "the scan finished before the kill: nothing was tested");
    assert!(!out.join("measurements.csv").exists());
    let port = fx.path("port");
    let o = run(&[
        "measure",
        "--port",
        s(&port),
        "--plan",
        s(&fx.plan),
        "--instrument",
        s(&fx.instrument),
        "-o",
        s(&out),
        "--resume",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    sim.stop();
    assert_eq!(csv_without_time(&out.join("measurements.csv")), want);
    let mut idx = journal_indices(&out);
    let lines = idx.len();
    idx.sort_unstable();
    idx.dedup();
    assert_eq!(idx.len(), N);
    assert_eq!(lines, N, "a direction was journaled twice");
}

#[test]
fn device_killed_mid_scan_is_reported_and_the_scan_resumes_when_it_returns() {
    let fx = Fixture::new(N, "");
    let want = reference(&fx);
    let mut sim = sim_on_link(&fx, 20.0);
    let out = fx.path("unplugged");
    let mut child = measure_child(&fx, &out, &["--reconnect-wait", "30"]);
    wait_for_records(&out, 10, &mut child);
    sim.restart().unwrap();
    let o = child.wait_with_output().unwrap();
    sim.stop();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("lost the device"), "{stderr}");
    assert!(stderr.contains("device is back"), "{stderr}");
    assert_eq!(csv_without_time(&out.join("measurements.csv")), want);
}

#[test]
fn a_limit_fault_mid_scan_is_reported_with_the_pose_and_the_journal_keeps_what_came_before() {
    let fx = Fixture::new(
        N,
        "[effects]\nlimit_fault = { axis = \"detector\", after_readings = 7 }\n",
    );
    let out = fx.path("fault");
    let o = fx.measure_sim(&fx.plan, &out);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(stderr.contains("LimitSwitch(Detector)"), "{stderr}");
    assert!(stderr.contains("detector") && stderr.contains("deg"), "{stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert_eq!(journal_indices(&out), (0..7).collect::<Vec<u32>>());
    assert!(!out.join("measurements.csv").exists());
}

#[test]
fn bad_inputs_fail_with_one_line_and_write_nothing() {
    let fx = Fixture::new(8, "");
    let out = fx.path("out");
    let (plan, inst, scene) = (s(&fx.plan), s(&fx.instrument), s(&fx.scene));
    let o = s(&out);
    // Missing port.
    assert_clean_failure(
        &[
            "measure",
            "--port",
            "/dev/does-not-exist",
            "--plan",
            plan,
            "--instrument",
            inst,
            "-o",
            o,
        ],
        &out,
        "cannot open port /dev/does-not-exist",
    );
    // A port with no gonio behind it: a pty nobody answers on.
    let pty = nix::pty::openpty(None, None).unwrap();
    let silent = nix::unistd::ttyname(pty.slave).unwrap();
    assert_clean_failure(
        &[
            "measure",
            "--port",
            s(&silent),
            "--plan",
            plan,
            "--instrument",
            inst,
            "-o",
            o,
            "--hello-timeout",
            "0.5",
        ],
        &out,
        "no gonio answered",
    );
    // A corrupt plan file.
    let bad_plan = fx.path("bad.bin");
    let mut bytes = std::fs::read(&fx.plan).unwrap();
    bytes[5] ^= 0x40;
    std::fs::write(&bad_plan, bytes).unwrap();
    assert_clean_failure(
        &[
            "measure",
            "--sim",
            scene,
            "--plan",
            s(&bad_plan),
            "--instrument",
            inst,
            "-o",
            o,
        ],
        &out,
        "damaged",
    );
    // An instrument file with impossible values.
    let bad_inst = fx.path("bad.toml");
    std::fs::write(
        &bad_inst,
        coarse_instrument_toml().replace("max_deg = 85.0", "max_deg = 95.0"),
    )
    .unwrap();
    assert_clean_failure(
        &[
            "measure",
            "--sim",
            scene,
            "--plan",
            plan,
            "--instrument",
            s(&bad_inst),
            "-o",
            o,
        ],
        &out,
        "tilt limits",
    );
    // A scene whose material does not parse.
    let bad_scene = fx.path("bad-scene.toml");
    std::fs::write(&bad_scene, SCENE.replace("ggx:alpha=0.2", "ggx:alpha=banana")).unwrap();
    assert_clean_failure(
        &[
            "measure",
            "--sim",
            s(&bad_scene),
            "--plan",
            plan,
            "--instrument",
            inst,
            "-o",
            o,
        ],
        &out,
        "bad-scene.toml",
    );
    let _ = nix::unistd::close(pty.master);
    let _ = nix::unistd::close(pty.slave);
}

#[test]
fn a_device_of_another_protocol_version_is_refused_with_a_clear_message() {
    use gonio_shared::frame::{encode, FrameDecoder, MAX_WIRE_FRAME};
    use gonio_shared::msg::{DeviceMsg, Hello, HostMsg};
    let fx = Fixture::new(8, "");
    let out = fx.path("out");
    let pty = nix::pty::openpty(None, None).unwrap();
    let mut t = nix::sys::termios::tcgetattr(pty.slave).unwrap();
    nix::sys::termios::cfmakeraw(&mut t);
    nix::sys::termios::tcsetattr(pty.slave, nix::sys::termios::SetArg::TCSANOW, &t).unwrap();
    let path = nix::unistd::ttyname(pty.slave).unwrap();
    let master = pty.master;
    // A fake device that answers every Hello with a newer protocol.
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let fake = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            let mut dec = FrameDecoder::new();
            let mut buf = [0u8; 256];
            while !stop.load(std::sync::atomic::Ordering::SeqCst) {
                let mut pfd = [nix::poll::PollFd::new(master, nix::poll::PollFlags::POLLIN)];
                if nix::poll::poll(&mut pfd, 20).unwrap_or(0) <= 0 {
                    continue;
                }
                let Ok(n) = nix::unistd::read(master, &mut buf) else {
                    continue;
                };
                for &b in &buf[..n] {
                    if let Some(Ok(f)) = dec.push::<HostMsg>(b) {
                        if let HostMsg::Hello(h) = f.msg {
                            let theirs = Hello {
                                protocol: Hello::OURS.protocol + 1,
                                schema: Hello::OURS.schema,
                                session: h.session,
                            };
                            let mut out = [0u8; MAX_WIRE_FRAME];
                            let k = encode(0, &DeviceMsg::Hello(theirs), &mut out).unwrap();
                            let _ = nix::unistd::write(master, &out[..k]);
                        }
                    }
                }
            }
        })
    };
    assert_clean_failure(
        &[
            "measure",
            "--port",
            s(&path),
            "--plan",
            s(&fx.plan),
            "--instrument",
            s(&fx.instrument),
            "-o",
            s(&out),
        ],
        &out,
        "protocol mismatch",
    );
    stop.store(true, std::sync::atomic::Ordering::SeqCst);
    fake.join().unwrap();
    let _ = nix::unistd::close(pty.master);
    let _ = nix::unistd::close(pty.slave);
}

#[test]
fn gonio_sim_serves_gonio_measure_over_its_published_port() {
    use std::io::BufRead;
    let fx = Fixture::new(16, "");
    let link = fx.path("sim-port");
    let mut sim = gonio()
        .args([
            "sim",
            "--scene",
            s(&fx.scene),
            "--instrument",
            s(&fx.instrument),
            "--speedup",
            "10000",
            "--link",
            s(&link),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut first = String::new();
    std::io::BufReader::new(sim.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    assert_eq!(first.trim(), s(&link), "gonio sim prints the port path");
    let out = fx.path("out");
    let o = run(&[
        "measure",
        "--port",
        first.trim(),
        "--plan",
        s(&fx.plan),
        "--instrument",
        s(&fx.instrument),
        "-o",
        s(&out),
    ]);
    sim.kill().unwrap();
    sim.wait().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("measured 16 directions"), "{stdout}");
    assert_eq!(csv_without_time(&out.join("measurements.csv")).len(), 16);
}

#[test]
fn an_unreachable_direction_is_reported_by_its_plan_index() {
    let fx = Fixture::new(8, "");
    let mut dirs = plan(12);
    dirs[9].theta_o = 95f32.to_radians(); // below the horizon
    let bad_plan = fx.path("unreachable.bin");
    gonio::plan::file::write_plan_file(&bad_plan, &dirs).unwrap();
    let out = fx.path("out");
    let o = fx.measure_sim(&bad_plan, &out);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("Unreachable { index: 9, reason: BelowHorizon"),
        "{stderr}"
    );
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(!out.join("measurements.csv").exists());
}

#[test]
fn after_a_limit_fault_the_scan_resumes_on_the_same_device_to_the_same_result() {
    let want = reference(&Fixture::new(N, ""));
    let fx = Fixture::new(
        N,
        "[effects]\nlimit_fault = { axis = \"light\", after_readings = 12 }\n",
    );
    let sim = sim_on_link(&fx, 10_000.0);
    let out = fx.path("fault-resume");
    let port = fx.path("port");
    let args = [
        "measure",
        "--port",
        s(&port),
        "--plan",
        s(&fx.plan),
        "--instrument",
        s(&fx.instrument),
        "-o",
        s(&out),
    ];
    let o = run(&args);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("LimitSwitch(Light)"));
    assert_eq!(journal_indices(&out), (0..12).collect::<Vec<u32>>());
    // The device is in a fault that needs homing; the resumed scan re-homes it and goes on.
    let o = run(&[&args[..], &["--resume"]].concat());
    sim.stop();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(csv_without_time(&out.join("measurements.csv")), want);
}
