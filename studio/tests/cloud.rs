//! The 3D point-cloud viewer drawn by the GPU (wgpu on Mesa's lavapipe): a cloud handed to the viewer as
//! the protocol delivers it comes out as lit pixels where its points are, and none where there are none.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use egui::Vec2;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable as _;
use kairos_protocol::frame::SampleHeader;
use kairos_studio::viewers::Viewers;

/// A flat disc of points 10 m across, 1.9 m under the sensor, with intensities, as frame bytes.
fn disc() -> (SampleHeader, Vec<u8>) {
    let mut bytes = Vec::new();
    for ring in 1..=40 {
        for step in 0..360 {
            let (radius, angle) = (ring as f32 * 0.25, (step as f32).to_radians());
            for value in [radius * angle.cos(), radius * angle.sin(), -1.9, 0.8] {
                bytes.extend_from_slice(&value.to_le_bytes());
            }
        }
    }
    let header = SampleHeader {
        output: "lidar.points".to_owned(),
        data_type: "point_cloud".to_owned(),
        timestamp_ns: 1,
        time_of_issue_ns: 2,
        sequence: 0,
        skipped: 0,
        value: None,
        image: None,
        intensity: true,
    };
    (header, bytes)
}

#[test]
fn the_gpu_draws_the_points_of_a_cloud() {
    let render_state = egui_kittest::wgpu::create_render_state(
        egui_kittest::wgpu::default_wgpu_setup(),
        eframe::egui_wgpu::RendererOptions::PREDICTABLE,
    );
    kairos_studio::cloud3d::install(&render_state);
    let renderer = egui_kittest::wgpu::WgpuTestRenderer::from_render_state(render_state.clone());
    let mut viewers = Viewers::default();
    viewers.open("lidar.points".to_owned(), "point_cloud");
    let (header, bytes) = disc();
    viewers.receive(&header, &bytes);
    assert_eq!(viewers.list[0].cloud_points(), 40 * 360);
    let mut harness = Harness::builder()
        .with_size(Vec2::new(640.0, 560.0))
        .renderer(renderer)
        .build_ui_state(|ui, viewers: &mut Viewers| viewers.show_docked(ui, &[]), viewers);
    harness.run_steps(3);
    let image = harness.render().unwrap();
    // The view is dark (grey 12) where no point falls; points are coloured. Count clearly coloured pixels
    // in the view's area (under the controls, above the caption).
    let lit = image
        .enumerate_pixels()
        .filter(|(_, y, p)| {
            (120..440).contains(y) && {
                let [r, g, b, _] = p.0;
                r.max(g).max(b) > 80
                    && (i16::from(r) - i16::from(b)).abs() + (i16::from(g) - i16::from(b)).abs() > 30
            }
        })
        .count();
    assert!(lit > 2_000, "only {lit} pixels show points");

    // Closing the viewer frees its GPU buffers.
    assert_eq!(kairos_studio::cloud3d::viewers_on_gpu(&render_state), 1);
    harness.get_by_label("Close").click();
    harness.run_steps(2);
    let closed = harness.state_mut().take_closed_on_gpu();
    assert_eq!(closed.len(), 1);
    kairos_studio::cloud3d::forget(&render_state, &closed);
    assert_eq!(kairos_studio::cloud3d::viewers_on_gpu(&render_state), 0);
}
