//! The calibrated pose over OpenIGTLink, received by clients no one here wrote: pyigtl and the
//! OpenIGTLink C++ library (see `kincal_e2e::peers`).

use kincal::controller::emulator::Emulator;
use kincal::controller::igtl_server::{PoseServer, ServerEvent, ServerOptions, DEFAULT_NAME};
use kincal::controller::pose_stream::{stream_poses, Flow, TimedPose};
use kincal::motion::trajectory::Trajectory;
use kincal_e2e::peers::{
    cpp_client, parse_cpp, parse_pyigtl, require_pyigtl, spawn_cpp, spawn_pyigtl, Peer, Received,
};
use kincal_e2e::{emulated_firmware, kincal_bin, FakeController};
use kincal_protocol::biss::counts_to_deg;
use kincal_protocol::messages::{Request, SimFaults, TICK_HZ};
use kincal_protocol::trajectory::counts_at;
use std::collections::BTreeMap;
use std::io::BufRead;
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kincal-igtl-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Host poses by timestamp (µs), for matching what a peer received.
fn by_time(poses: &[TimedPose]) -> BTreeMap<i64, TimedPose> {
    poses.iter().map(|p| ((igtl_seconds(p.t_s) * 1e6).round() as i64, *p)).collect()
}

/// The timestamp a pose is sent with, as the wire carries it (ns resolution).
fn igtl_seconds(t_s: f64) -> f64 {
    kincal::igtl::unix_seconds(kincal::igtl::timestamp(t_s))
}

/// The host pose a peer's message is of (timestamps agree within 2 µs).
fn pose_of(host: &BTreeMap<i64, TimedPose>, m: &Received) -> TimedPose {
    let key = (m.t_s * 1e6).round() as i64;
    let found = host.range(key - 2..=key + 2).next().map(|(_, p)| *p);
    found.unwrap_or_else(|| panic!("{} at {:.6} s matches no pose the host streamed", m.kind, m.t_s))
}

/// Largest difference between a received matrix and the host's pose, mm (positions) and unit
/// (axes).
fn difference(m: &[f64], pose: &TimedPose) -> f64 {
    let rows = pose.rows();
    assert_eq!(m.len(), 12, "{m:?}");
    (0..12).map(|k| (m[k] - rows[k % 3][k / 3] as f64).abs()).fold(0.0, f64::max)
}

fn stdout_of(peer: Peer) -> String {
    let (status, out) = peer.finish();
    assert!(status.success(), "a peer failed: {status:?}");
    out
}

/// 60 s of the emulated controller's calibrated pose at 768 Hz, moving along a trajectory, to
/// pyigtl (header version 2), the C++ library's client (header version 1), a C++ client that
/// asks for 50 ms, a client that never reads and one that leaves; joint 3 unplugged for 2 s in
/// the middle. Every client that reads gets every message (0 lost), matrices equal the host's
/// pose to 1 µm and the host's pose equals the model's forward kinematics of the encoder counts
/// the trajectory gives to 1 µm; invalid poses reach pyigtl marked INVALID with a NaN matrix and
/// the C++ client as STATUS only, never as a transform; the controller link loses nothing.
#[test]
fn pyigtl_and_the_cpp_library_receive_the_moving_pose_for_a_minute() {
    require_pyigtl();
    let cpp = cpp_client(std::path::Path::new(env!("CARGO_TARGET_TMPDIR")));
    let dir = scratch("peers");
    let (_emulator, mut link) = Emulator::start(&emulated_firmware()).expect("QEMU starts");
    link.hello().unwrap();
    let mut model = kincal::model::ArmModel::suta_nominal();
    model.joints[1].compliance_deg_per_m = 0.3;
    model.tcp_mm = [0.4, -0.2, 253.0];
    link.upload(&kincal_e2e::signed_set(&model, 1)).unwrap();
    let trajectory = Trajectory::demo([20.0, 100.0, 40.0, 10.0, 70.0, 5.0]);
    let start_tick = kincal::controller::motion::play(&mut link, &trajectory, true).unwrap();
    let options = ServerOptions { send_invalid: true, ..ServerOptions::default() };
    let server = PoseServer::start("127.0.0.1:0", options).unwrap();
    let addr = server.local_addr();
    let py_csv = dir.join("pyigtl.csv");
    let python = spawn_pyigtl(addr, &py_csv, true);
    let plain = spawn_cpp(&cpp, addr, None);
    let rated = spawn_cpp(&cpp, addr, Some(50));
    let stalled = TcpStream::connect(addr).unwrap();
    let leaver = TcpStream::connect(addr).unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while server.clients().len() < 5 {
        assert!(Instant::now() < deadline, "the clients did not connect: {:?}", server.clients());
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500)); // pyigtl's header-2 message arrives
    let mut poses: Vec<TimedPose> = Vec::new();
    let mut leaver = Some(leaver);
    let started = Instant::now();
    let last_valid = std::cell::Cell::new(None);
    let count = stream_poses(
        &mut link,
        Some(&server),
        |p| {
            poses.push(*p);
            last_valid.set(Some(p.report.valid));
        },
        |link, _| {
            let t = started.elapsed().as_secs_f64();
            if t > 5.0 {
                leaver = None;
            }
            let unplug = |unplugged| SimFaults { unplugged, ..SimFaults::default() };
            match last_valid.get() {
                Some(true) if (20.0..22.0).contains(&t) => link.call(unplug(0b100))?,
                Some(false) if t >= 22.0 => link.call(unplug(0))?,
                _ => kincal_protocol::messages::Ack,
            };
            Ok(if t >= 60.0 { Flow::Stop } else { Flow::Go })
        },
    )
    .unwrap();
    let stats = server.clients();
    let events = server.events();
    drop(server); // the clients see the connection close and write out what they got
    let (plain, rated, python) =
        (parse_cpp(&stdout_of(plain)), parse_cpp(&stdout_of(rated)), stdout_of(python));
    drop(stalled);

    // The controller link: every tick, nothing lost or corrupt, the invalid stretch as asked.
    assert_eq!((count.lost, count.corrupt), (0, 0), "{count:?}");
    assert!(poses.len() as f64 >= 60.0 * TICK_HZ as f64 * 0.98, "{} poses in 60 s", poses.len());
    assert!(poses.windows(2).all(|w| w[1].tick == w[0].tick + 1), "a tick is missing in the host's stream");
    let invalid = poses.iter().filter(|p| !p.report.valid).count();
    assert!((1200..2000).contains(&invalid), "{invalid} invalid poses for 2 s unplugged");
    // The host's pose is the calibrated model's forward kinematics of the counts the trajectory
    // gave the encoders at that tick.
    for p in poses.iter().filter(|p| p.report.valid).step_by(97) {
        let counts = counts_at(&trajectory.waypoints, (p.tick as u32).wrapping_sub(start_tick), true);
        let deg = counts.map(|c| counts_to_deg(c as f64));
        let fk = kincal::model::kinematics::tool_pose(&model, &deg).position_mm;
        let d = (0..3).map(|k| (p.report.position_mm[k] as f64 - fk[k]).powi(2)).sum::<f64>().sqrt();
        assert!(
            d < 1e-3,
            "tick {}: streamed {:?}, forward kinematics {fk} ({d} mm)",
            p.tick,
            p.report.position_mm
        );
    }
    let moved = poses
        .iter()
        .filter(|p| p.report.valid)
        .map(|p| p.report.position_mm[0])
        .fold((f32::MAX, f32::MIN), |(a, b), x| (a.min(x), b.max(x)));
    assert!(moved.1 - moved.0 > 30.0, "the arm moved {moved:?}");
    let host = by_time(&poses);
    let window = |got: &[Received]| {
        let t: Vec<f64> = got.iter().filter(|m| m.kind != "RTS_TDATA").map(|m| m.t_s).collect();
        let (first, last) =
            (t.iter().cloned().fold(f64::MAX, f64::min), t.iter().cloned().fold(f64::MIN, f64::max));
        poses
            .iter()
            .filter(move |p| igtl_seconds(p.t_s) >= first - 1e-6 && igtl_seconds(p.t_s) <= last + 1e-6)
    };

    // pyigtl, header version 2 with send_invalid: every tick, marked.
    let py = parse_pyigtl(&std::fs::read_to_string(&py_csv).unwrap());
    assert!(python.contains("CLOSED"), "{python}");
    let transforms: Vec<&Received> = py.iter().filter(|m| m.kind == "TRANSFORM").collect();
    let expected = window(&py).count();
    assert_eq!(transforms.len(), expected, "pyigtl lost transforms");
    assert!(py.iter().all(|m| m.crc_ok && m.device == DEFAULT_NAME), "pyigtl's CRC-64 or name");
    let v1 = transforms.iter().take_while(|m| m.version == 1).count();
    assert!(v1 < 768 && transforms[v1..].iter().all(|m| m.version == 2), "header version 2 after its hello");
    let (mut marked, mut worst) = (0, 0.0f64);
    for m in &transforms[v1..] {
        let pose = pose_of(&host, m);
        if pose.report.valid {
            assert_eq!(m.status, "OK", "{m:?}");
            worst = worst.max(difference(&m.matrix, &pose));
        } else {
            assert_eq!(m.status, "INVALID", "an invalid pose reached pyigtl unmarked: {m:?}");
            assert!(m.matrix.iter().all(|v| v.is_nan()), "an invalid pose carried numbers: {m:?}");
            marked += 1;
        }
    }
    assert!(worst < 1e-3, "pyigtl's matrices differ from the host's pose by {worst}");
    assert_eq!(marked, invalid, "every invalid tick reached pyigtl marked INVALID");

    // The C++ library, header version 1: every valid pose, no transform for an invalid one, a
    // STATUS naming joint 3 when it went and an OK when it came back.
    let transforms: Vec<&Received> = plain.iter().filter(|m| m.kind == "TRANSFORM").collect();
    let expected: Vec<&TimedPose> = window(&plain).filter(|p| p.report.valid).collect();
    // The window is the span the client received: it must be the whole minute, or a client that
    // stopped reading would pass unseen.
    let span = transforms.last().map_or(0.0, |m| m.t_s) - transforms.first().map_or(0.0, |m| m.t_s);
    assert!(span > 55.0, "the C++ client received {span:.1} s of the 60 s stream");
    assert_eq!(transforms.len(), expected.len(), "the C++ client lost transforms");
    assert!(plain.iter().all(|m| m.crc_ok), "the library's CRC check failed");
    let worst = transforms.iter().map(|m| difference(&m.matrix, &pose_of(&host, m))).fold(0.0, f64::max);
    assert!(worst < 1e-3, "the C++ client's matrices differ from the host's pose by {worst}");
    assert!(
        transforms.iter().all(|m| pose_of(&host, m).report.valid),
        "an invalid pose reached the C++ client as a transform"
    );
    let status: Vec<(i64, i64)> = plain.iter().filter_map(|m| m.code).collect();
    assert!(status.len() >= 3 && status[..status.len() - 1].iter().all(|c| *c == (18, 0b100)), "{status:?}");
    assert_eq!(status.last(), Some(&(1, 0)), "{status:?}");

    // The client that asked for 50 ms: TDATA no closer than that, about 20 Hz.
    let tdata: Vec<&Received> = rated.iter().skip_while(|m| m.kind != "RTS_TDATA").skip(1).collect();
    assert!(tdata.iter().all(|m| m.kind == "TDATA" || m.kind == "STATUS"), "only TDATA after RTS_TDATA");
    let times: Vec<f64> = tdata.iter().filter(|m| m.kind == "TDATA").map(|m| m.t_s).collect();
    assert!(times.windows(2).all(|w| w[1] - w[0] >= 0.050 - 1e-6), "TDATA closer than 50 ms");
    assert!((1000..1250).contains(&times.len()), "{} TDATA messages in a minute", times.len());
    let worst = tdata
        .iter()
        .filter(|m| m.kind == "TDATA")
        .map(|m| difference(&m.matrix, &pose_of(&host, m)))
        .fold(0.0, f64::max);
    assert!(worst < 1e-3, "TDATA differs from the host's pose by {worst}");

    // The client that never read lost its oldest frames, and only it; the leaver was logged.
    let stalled_stats = stats.iter().max_by_key(|c| c.dropped).unwrap();
    assert!(stalled_stats.dropped > 10_000, "{stats:?}");
    assert_eq!(stats.iter().filter(|c| c.dropped > 0).count(), 1, "{stats:?}");
    assert!(events.iter().any(|e| matches!(e, ServerEvent::Slow { .. })), "{events:?}");
    assert!(events.iter().any(|e| matches!(e, ServerEvent::Left { .. })), "{events:?}");
    std::fs::remove_dir_all(&dir).ok();
}

/// `kincal stream --pose --igtl` on the in-process fake controller: pyigtl (header version 1,
/// PLUS's default of sending valid transforms only) gets the transforms, none while joint 3 is
/// unplugged, and the CLI logs the client.
#[test]
fn the_stream_command_serves_the_pose_and_keeps_invalid_poses_back() {
    require_pyigtl();
    let fake = FakeController::start(1);
    let dir = scratch("cli");
    let mut link = kincal::controller::link::Link::open(&fake.port).unwrap();
    link.hello().unwrap();
    link.upload(&kincal_e2e::signed_set(&kincal::model::ArmModel::suta_nominal(), 1)).unwrap();
    drop(link);
    let csv = dir.join("poses.csv");
    // It streams until interrupted (Ctrl-C), so a slow machine cannot end it before pyigtl is in.
    let mut child = Command::new(kincal_bin())
        .args(["stream", "--port", &fake.port, "--pose", "--igtl", "127.0.0.1:0", "--seconds", "300"])
        .arg("--csv")
        .arg(&csv)
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(dir.join("stream.err")).unwrap())
        .spawn()
        .unwrap();
    let mut stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    stdout.read_line(&mut line).unwrap();
    let addr: std::net::SocketAddr = line
        .strip_prefix("OpenIGTLink server on ")
        .and_then(|r| r.split(':').take(2).collect::<Vec<_>>().join(":").parse().ok())
        .unwrap_or_else(|| panic!("{line}"));
    let (lines, printed) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in stdout.lines().map_while(Result::ok) {
            let _ = lines.send(line);
        }
    });
    let py_csv = dir.join("py.csv");
    let python = spawn_pyigtl(addr, &py_csv, false);
    // kincal's own recording client, as `kincal dynamic` takes the pose from the OpenIGTLink side.
    let recorded = dir.join("igtl-record.csv");
    let recorder = Peer::start(
        Command::new(kincal_bin())
            .args(["igtl-record", "--connect", &addr.to_string(), "--csv"])
            .arg(&recorded),
        "kincal igtl-record starts",
    );
    let mut rest = Vec::new();
    let joined = |lines: &[String]| {
        lines.iter().filter(|l| l.contains("OpenIGTLink client") && l.contains("connected")).count()
    };
    while joined(&rest) < 2 {
        rest.push(
            printed.recv_timeout(Duration::from_secs(120)).expect("the CLI logs both clients' connections"),
        );
    }
    std::thread::sleep(Duration::from_millis(1200));
    fake.meddle_arm(Request::SimFaults(SimFaults { unplugged: 0b100, ..SimFaults::default() }));
    std::thread::sleep(Duration::from_millis(800));
    fake.meddle_arm(Request::SimFaults(SimFaults::default()));
    std::thread::sleep(Duration::from_millis(1000));
    let interrupted = Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
    assert!(interrupted.success());
    rest.extend(printed.iter());
    let rest = rest.join("\n");
    let status = child.wait().unwrap();
    let errors = std::fs::read_to_string(dir.join("stream.err")).unwrap_or_default();
    assert!(status.success(), "kincal stream ended {status:?}: {rest}\n{errors}");
    let _ = stdout_of(python);
    let said = stdout_of(recorder);
    assert!(said.contains("poses in") && said.contains("written to"), "{said}");
    let got = parse_pyigtl(&std::fs::read_to_string(&py_csv).unwrap());
    // The host's CSV: t_s of every valid and invalid row.
    let text = std::fs::read_to_string(&csv).unwrap();
    let rows: Vec<(bool, f64)> = text
        .lines()
        .skip(1)
        .map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            (c[2] == "1", c[14].parse::<f64>().unwrap())
        })
        .collect();
    let invalid: Vec<f64> = rows.iter().filter(|r| !r.0).map(|r| igtl_seconds(r.1)).collect();
    assert!(invalid.len() > 300, "{} invalid rows", invalid.len());
    let transforms: Vec<&Received> = got.iter().filter(|m| m.kind == "TRANSFORM").collect();
    assert!(transforms.len() > 1500, "{} transforms", transforms.len());
    assert!(transforms.iter().all(|m| m.version == 1 && m.crc_ok && m.status.is_empty()));
    let near_invalid = |t: f64| invalid.iter().any(|i| (i - t).abs() < 2e-6);
    assert!(!transforms.iter().any(|m| near_invalid(m.t_s)), "an invalid pose was sent as a transform");
    assert!(got.iter().filter(|m| m.kind == "STATUS").count() >= 2, "pyigtl saw no STATUS");
    // `kincal igtl-record` wrote every valid pose streamed while it was connected, and no other.
    let positions: BTreeMap<i64, [f64; 3]> = text
        .lines()
        .skip(1)
        .filter(|l| l.split(',').nth(2) == Some("1"))
        .map(|l| {
            let c: Vec<f64> = l.split(',').map(|v| v.parse().unwrap_or(f64::NAN)).collect();
            ((igtl_seconds(c[14]) * 1e6).round() as i64, [c[5], c[6], c[7]])
        })
        .collect();
    let track = kincal::motion::recording::read_track(&recorded).unwrap();
    assert!(track.len() > 1500 && track.host_s.is_some(), "{} rows", track.len());
    for (t, p) in track.t_s.iter().zip(&track.p) {
        let key = (t * 1e6).round() as i64;
        let host = positions.range(key - 1..=key + 1).next().map(|(_, p)| p);
        let host = host.unwrap_or_else(|| panic!("{t}: no valid pose streamed then"));
        assert!((0..3).all(|k| (host[k] - p[k]).abs() < 1e-3), "{t}: {p:?} vs {host:?}");
    }
    let (first, last) = (track.t_s[0], track.t_s[track.len() - 1]);
    let streamed =
        rows.iter().filter(|r| r.0 && (first - 1e-6..=last + 1e-6).contains(&igtl_seconds(r.1))).count();
    assert_eq!(track.len(), streamed, "igtl-record lost poses");
    std::fs::remove_dir_all(&dir).ok();
}
