//! The controller's f32 kinematics agrees with the host's f64 kinematics to ≤ 1 µm over the
//! workspace, for every effect the host model can hold.

use kincal::controller::device::{device_params, parameter_blob};
use kincal::model::kinematics::tool_pose;
use kincal::model::{ArmModel, Convention};
use kincal_firmware::kinematics as device;
use kincal_protocol::biss::COUNTS_PER_TURN;
use kincal_protocol::params::decode_blob;
use rand::{RngExt, SeedableRng};

fn with_every_effect(convention: Convention) -> ArmModel {
    let mut m = ArmModel::suta_nominal();
    m.convention = convention;
    for (j, row) in m.joints.iter_mut().enumerate() {
        let s = j as f64 + 1.0;
        row.offset_deg += 0.37 * s;
        row.d_mm += 0.2 * s;
        row.a_mm = 0.3 * s;
        row.alpha_deg += 0.05 * s;
        row.axis_deg = 0.02 * s;
        row.eccentricity_sin_deg = 0.03 * s;
        row.eccentricity_cos_deg = -0.02 * s;
        row.eccentricity2_sin_deg = 0.01;
        row.eccentricity2_cos_deg = -0.01;
        row.compliance_deg_per_m = 0.05 * s;
    }
    m.tcp_mm = [0.4, -0.3, 252.7];
    m.scale_ppm = 120.0;
    m
}

#[test]
fn device_pose_matches_the_host_within_a_micrometre() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(12);
    let mut worst_um: f64 = 0.0;
    for convention in [Convention::Classic, Convention::Modified] {
        let model = with_every_effect(convention);
        // The blob round trip is part of the path the controller takes.
        let params = decode_blob(&parameter_blob(&model, 3).unwrap()).expect("blob decodes");
        assert_eq!(params, device_params(&model, 3).expect("six joints"));
        let kinematics = device::Kinematics::new(&params);
        for _ in 0..20_000 {
            let counts: [u32; 6] = std::array::from_fn(|_| rng.random_range(0..COUNTS_PER_TURN));
            let enc_deg = counts.map(|c| kincal_protocol::biss::counts_to_deg(c as f64));
            let host = tool_pose(&model, &enc_deg);
            let dev = kinematics.tool_pose(&counts);
            let dp =
                (0..3).map(|k| (host.position_mm[k] - dev.position_mm[k] as f64).powi(2)).sum::<f64>().sqrt();
            worst_um = worst_um.max(dp * 1000.0);
            let dz = (0..3).map(|k| (host.z_axis[k] - dev.z_axis[k] as f64).abs()).fold(0.0, f64::max);
            assert!(dz < 1e-6, "tool axis differs by {dz}");
        }
    }
    eprintln!("largest host/device position difference: {worst_um:.3} µm");
    assert!(worst_um <= 1.0, "device kinematics off by {worst_um} µm");
}
