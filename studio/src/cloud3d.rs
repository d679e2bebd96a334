//! The 3D point-cloud view: points drawn by the GPU inside egui's own render pass (a wgpu paint callback),
//! each a small screen-aligned square, coloured by height or intensity, seen through an orbit camera
//! (drag to turn, right or middle drag to pan, scroll to zoom). The points are uploaded once per new cloud,
//! not per frame.

use std::collections::HashMap;
use std::sync::Arc;

use eframe::egui_wgpu::{self, CallbackResources, CallbackTrait, RenderState, ScreenDescriptor};
use eframe::wgpu;
use glam::{Mat4, Vec3};

/// Whether [`install`] ran: without it there is no pipeline to draw with.
static INSTALLED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Whether the 3D view can draw (the GPU renderer is there and the pipeline installed).
pub fn available() -> bool {
    INSTALLED.load(std::sync::atomic::Ordering::Relaxed)
}

/// How points are coloured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorBy {
    /// Height (z) from blue (low) to red (high).
    Height,
    /// Intensity from dark to bright.
    Intensity,
}

/// A cloud ready for the GPU: x, y, z and intensity per point, with a number that changes with the cloud.
#[derive(Debug, Default)]
pub struct GpuCloud {
    /// Changes whenever the points do.
    pub generation: u64,
    /// x, y, z, intensity.
    pub points: Vec<[f32; 4]>,
    /// The lowest and highest z, for colouring by height.
    pub z_range: (f32, f32),
}

/// The orbit camera: it looks at `target` from `distance` away, turned by `yaw` and `pitch` (radians).
#[derive(Debug, Clone, Copy)]
pub struct OrbitCamera {
    /// The point looked at.
    pub target: Vec3,
    /// Distance from the target, metres.
    pub distance: f32,
    /// Turn around the vertical (z) axis.
    pub yaw: f32,
    /// Elevation above the horizontal.
    pub pitch: f32,
}

impl Default for OrbitCamera {
    fn default() -> Self {
        // Behind and above a sensor that looks along +x, as a driver would see the scene.
        OrbitCamera {
            target: Vec3::new(8.0, 0.0, 0.0),
            distance: 40.0,
            yaw: std::f32::consts::PI,
            pitch: 0.5,
        }
    }
}

impl OrbitCamera {
    fn eye(&self) -> Vec3 {
        let direction = Vec3::new(
            self.pitch.cos() * self.yaw.cos(),
            self.pitch.cos() * self.yaw.sin(),
            self.pitch.sin(),
        );
        self.target + direction * self.distance
    }

    /// World to clip space for a view `aspect` wide per unit of height.
    pub fn view_projection(&self, aspect: f32) -> Mat4 {
        let view = Mat4::look_at_rh(self.eye(), self.target, Vec3::Z);
        let projection = Mat4::perspective_rh(55_f32.to_radians(), aspect.max(0.01), 0.1, 2000.0);
        projection * view
    }

    /// Applies a frame's pointer input over the view.
    pub fn handle(&mut self, response: &egui::Response, ui: &egui::Ui) {
        if response.dragged_by(egui::PointerButton::Primary) {
            let delta = response.drag_delta();
            self.yaw -= delta.x * 0.008;
            self.pitch = (self.pitch + delta.y * 0.008).clamp(-1.5, 1.5);
        }
        if response.dragged_by(egui::PointerButton::Secondary)
            || response.dragged_by(egui::PointerButton::Middle)
        {
            let delta = response.drag_delta() * self.distance * 0.002;
            let right = Vec3::new(-self.yaw.sin(), self.yaw.cos(), 0.0);
            let forward = Vec3::new(-self.yaw.cos(), -self.yaw.sin(), 0.0);
            self.target += right * delta.x + forward * delta.y;
        }
        if response.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y);
            if scroll != 0.0 {
                self.distance = (self.distance * (-scroll * 0.002).exp()).clamp(1.0, 1500.0);
            }
        }
    }
}

#[repr(C)]
#[derive(Debug, Clone, Copy)]
struct Uniforms {
    view_projection: [[f32; 4]; 4],
    /// Viewport width and height in pixels, point size in pixels, colour mode (0 height, 1 intensity).
    viewport: [f32; 4],
    /// Lowest and highest z, then padding.
    z_range: [f32; 4],
}

impl Uniforms {
    fn bytes(&self) -> Vec<u8> {
        let mut bytes = Vec::with_capacity(96);
        for column in self.view_projection {
            for value in column {
                bytes.extend_from_slice(&value.to_le_bytes());
            }
        }
        for value in self.viewport.iter().chain(&self.z_range) {
            bytes.extend_from_slice(&value.to_le_bytes());
        }
        bytes
    }
}

const SHADER: &str = r"
struct Uniforms {
    view_projection: mat4x4<f32>,
    viewport: vec4<f32>,
    z_range: vec4<f32>,
};
@group(0) @binding(0) var<uniform> u: Uniforms;

struct Out {
    @builtin(position) position: vec4<f32>,
    @location(0) color: vec3<f32>,
};

fn ramp(t: f32) -> vec3<f32> {
    let x = clamp(t, 0.0, 1.0);
    return clamp(vec3<f32>(1.5 - abs(4.0 * x - 3.0), 1.5 - abs(4.0 * x - 2.0), 1.5 - abs(4.0 * x - 1.0)), vec3<f32>(0.0), vec3<f32>(1.0));
}

@vertex
fn vs(@builtin(vertex_index) corner_index: u32, @location(0) point: vec4<f32>) -> Out {
    var corners = array<vec2<f32>, 6>(
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, -1.0), vec2<f32>(1.0, 1.0),
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, 1.0), vec2<f32>(-1.0, 1.0));
    var clip = u.view_projection * vec4<f32>(point.xyz, 1.0);
    let corner = corners[corner_index];
    clip = vec4<f32>(clip.xy + corner * u.viewport.z / u.viewport.xy * clip.w, clip.zw);
    var out: Out;
    out.position = clip;
    if (point.w < 0.0) {
        // A marker (a box's edges): the same colour in every mode, one neither ramp uses.
        out.color = vec3<f32>(1.0, 0.2, 1.0);
    } else if (u.viewport.w < 0.5) {
        let span = max(u.z_range.y - u.z_range.x, 0.001);
        out.color = ramp((point.z - u.z_range.x) / span);
    } else {
        let i = clamp(point.w, 0.0, 1.0);
        out.color = vec3<f32>(0.15 + 0.85 * i, 0.15 + 0.85 * i, 0.25 + 0.75 * i);
    }
    return out;
}

@fragment
fn fs(in: Out) -> @location(0) vec4<f32> {
    return vec4<f32>(in.color, 1.0);
}
";

/// One viewer's GPU buffers.
#[allow(missing_debug_implementations, reason = "GPU handles with nothing to show")]
struct ViewerBuffers {
    points: wgpu::Buffer,
    capacity: usize,
    count: u32,
    generation: u64,
    uniforms: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

/// What the paint callbacks share: the pipeline, and each viewer's buffers.
#[allow(missing_debug_implementations, reason = "GPU handles with nothing to show")]
pub struct CloudRenderer {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    viewers: HashMap<u64, ViewerBuffers>,
}

/// Makes the point pipeline for the renderer's target format and keeps it among the callback resources.
/// The studio calls it once at start; without it the 3D view says it cannot draw.
pub fn install(render_state: &RenderState) {
    INSTALLED.store(true, std::sync::atomic::Ordering::Relaxed);
    let device = &render_state.device;
    let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("kairos point cloud"),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("kairos point cloud"),
        entries: &[wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::VERTEX,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        }],
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("kairos point cloud"),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("kairos point cloud"),
        layout: Some(&pipeline_layout),
        vertex: wgpu::VertexState {
            module: &shader,
            entry_point: Some("vs"),
            compilation_options: wgpu::PipelineCompilationOptions::default(),
            buffers: &[Some(wgpu::VertexBufferLayout {
                array_stride: 16,
                step_mode: wgpu::VertexStepMode::Instance,
                attributes: &wgpu::vertex_attr_array![0 => Float32x4],
            })],
        },
        fragment: Some(wgpu::FragmentState {
            module: &shader,
            entry_point: Some("fs"),
            compilation_options: wgpu::PipelineCompilationOptions::default(),
            targets: &[Some(render_state.target_format.into())],
        }),
        primitive: wgpu::PrimitiveState::default(),
        depth_stencil: None,
        multisample: wgpu::MultisampleState::default(),
        multiview_mask: None,
        cache: None,
    });
    render_state
        .renderer
        .write()
        .callback_resources
        .insert(CloudRenderer {
            pipeline,
            layout,
            viewers: HashMap::new(),
        });
}

/// One frame's drawing of one viewer's cloud.
#[derive(Debug)]
pub struct CloudCallback {
    /// The viewer's id (its buffers).
    pub viewer: u64,
    /// The cloud.
    pub cloud: Arc<GpuCloud>,
    /// World to clip space.
    pub view_projection: Mat4,
    /// Point size in pixels.
    pub point_size: f32,
    /// The colouring.
    pub color_by: ColorBy,
    /// The size of the view in points.
    pub rect_size: egui::Vec2,
}

impl CallbackTrait for CloudCallback {
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        screen: &ScreenDescriptor,
        _encoder: &mut wgpu::CommandEncoder,
        resources: &mut CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        let Some(renderer) = resources.get_mut::<CloudRenderer>() else {
            return Vec::new();
        };
        let needed = self.cloud.points.len().max(1);
        let stale = renderer
            .viewers
            .get(&self.viewer)
            .is_none_or(|b| b.capacity < needed);
        if stale {
            let capacity = needed.next_power_of_two();
            let points = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("kairos point cloud points"),
                size: (capacity * 16) as u64,
                usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let uniforms = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("kairos point cloud uniforms"),
                size: 96,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("kairos point cloud"),
                layout: &renderer.layout,
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: uniforms.as_entire_binding(),
                }],
            });
            renderer.viewers.insert(
                self.viewer,
                ViewerBuffers {
                    points,
                    capacity,
                    count: 0,
                    generation: u64::MAX,
                    uniforms,
                    bind_group,
                },
            );
        }
        let Some(buffers) = renderer.viewers.get_mut(&self.viewer) else {
            return Vec::new();
        };
        if buffers.generation != self.cloud.generation {
            let mut bytes = Vec::with_capacity(self.cloud.points.len() * 16);
            for point in &self.cloud.points {
                for value in point {
                    bytes.extend_from_slice(&value.to_le_bytes());
                }
            }
            queue.write_buffer(&buffers.points, 0, &bytes);
            buffers.count = u32::try_from(self.cloud.points.len()).unwrap_or(u32::MAX);
            buffers.generation = self.cloud.generation;
        }
        let uniforms = Uniforms {
            view_projection: self.view_projection.to_cols_array_2d(),
            viewport: [
                self.rect_size.x * screen.pixels_per_point,
                self.rect_size.y * screen.pixels_per_point,
                self.point_size * screen.pixels_per_point,
                match self.color_by {
                    ColorBy::Height => 0.0,
                    ColorBy::Intensity => 1.0,
                },
            ],
            z_range: [self.cloud.z_range.0, self.cloud.z_range.1, 0.0, 0.0],
        };
        queue.write_buffer(&buffers.uniforms, 0, &uniforms.bytes());
        Vec::new()
    }

    fn paint(
        &self,
        info: egui::PaintCallbackInfo,
        render_pass: &mut wgpu::RenderPass<'static>,
        resources: &CallbackResources,
    ) {
        let Some(renderer) = resources.get::<CloudRenderer>() else {
            return;
        };
        let Some(buffers) = renderer.viewers.get(&self.viewer) else {
            return;
        };
        // egui has set the viewport to the callback's rect, whose size the uniforms carry.
        let _ = info;
        render_pass.set_pipeline(&renderer.pipeline);
        render_pass.set_bind_group(0, &buffers.bind_group, &[]);
        render_pass.set_vertex_buffer(0, buffers.points.slice(..));
        render_pass.draw(0..6, 0..buffers.count);
    }
}

/// How much an adapter is preferred: a real GPU first; without one, software OpenGL (llvmpipe) before
/// software Vulkan (lavapipe). Mesa 22's lavapipe keeps about 300 KB in its queue thread for every frame
/// that draws the point cloud, whatever its size (a heap profile shows it; the same frames skip the draw
/// and do not grow), so the studio's RSS grew 4 MB/s with a 3D view open; llvmpipe through OpenGL does not.
fn adapter_rank(info: &wgpu::AdapterInfo) -> u8 {
    match (info.device_type, info.backend) {
        (wgpu::DeviceType::DiscreteGpu, _) => 0,
        (wgpu::DeviceType::IntegratedGpu, _) => 1,
        (wgpu::DeviceType::VirtualGpu, _) => 2,
        (_, wgpu::Backend::Gl) => 3,
        (wgpu::DeviceType::Other, _) => 4,
        (wgpu::DeviceType::Cpu, _) => 5,
    }
}

/// No adapter wgpu found can present to the studio's window.
#[derive(Debug, Clone, thiserror::Error)]
#[error(
    "no graphics adapter can draw in this window (found: {}); install Mesa's drivers \
     (Debian: mesa-vulkan-drivers libgl1-mesa-dri)",
    listed(.found)
)]
pub struct NoAdapterError {
    /// Every adapter found, those that cannot present included.
    pub found: Vec<wgpu::AdapterInfo>,
}

/// The adapters found, `name (backend)` each, or `none`.
fn listed(found: &[wgpu::AdapterInfo]) -> String {
    if found.is_empty() {
        "none".to_owned()
    } else {
        found
            .iter()
            .map(|info| format!("{} ({:?})", info.name, info.backend))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Picks the adapter the studio draws with among those wgpu found (see [`adapter_rank`]), keeping to those
/// that can present to the window. `WGPU_BACKEND` still limits which are found.
///
/// # Errors
/// When no adapter can present to the window.
pub fn choose_adapter(
    adapters: &[wgpu::Adapter],
    surface: Option<&wgpu::Surface<'_>>,
) -> Result<wgpu::Adapter, NoAdapterError> {
    adapters
        .iter()
        .filter(|a| surface.is_none_or(|s| a.is_surface_supported(s)))
        .min_by_key(|a| adapter_rank(&a.get_info()))
        .cloned()
        .ok_or_else(|| NoAdapterError {
            found: adapters.iter().map(wgpu::Adapter::get_info).collect(),
        })
}

/// Frees the GPU buffers of the 3D viewers `closed`.
pub fn forget(render_state: &RenderState, closed: &[u64]) {
    if closed.is_empty() {
        return;
    }
    let mut renderer = render_state.renderer.write();
    if let Some(clouds) = renderer.callback_resources.get_mut::<CloudRenderer>() {
        for viewer in closed {
            clouds.viewers.remove(viewer);
        }
    }
}

/// How many 3D viewers hold GPU buffers.
pub fn viewers_on_gpu(render_state: &RenderState) -> usize {
    render_state
        .renderer
        .read()
        .callback_resources
        .get::<CloudRenderer>()
        .map_or(0, |clouds| clouds.viewers.len())
}

/// Shows the cloud in `rect` of `ui`, through `camera`.
pub fn paint(ui: &egui::Ui, rect: egui::Rect, callback: CloudCallback) {
    ui.painter()
        .add(egui_wgpu::Callback::new_paint_callback(rect, callback));
}
