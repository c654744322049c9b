//! The 3D viewport: an orbit camera and a small wgpu renderer (lit triangles and lines with
//! their own depth buffer) drawn through an egui_wgpu paint callback.
//!
//! The scene renders into an offscreen colour + depth target in `prepare`, and `paint` blits
//! it into egui's pass; egui's pass need not have a depth buffer (the headless test renderer
//! has none).

use std::sync::Arc;

use eframe::egui_wgpu::{self, wgpu};
use nalgebra::{Matrix4, Perspective3, Point3, Vector3};
use wgpu::util::DeviceExt;

/// A vertex of the lit surface.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SurfaceVertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    /// Gamma-space colour.
    pub color: [f32; 3],
}

/// A vertex of the unlit lines (wireframe, crosses).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LineVertex {
    pub position: [f32; 3],
    pub color: [f32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct Uniforms {
    view_proj: [[f32; 4]; 4],
    eye: [f32; 4],
    light: [f32; 4],
}

/// What to draw this frame (built on the CPU from the session's frame).
#[derive(Default)]
pub struct Scene {
    pub vertices: Vec<SurfaceVertex>,
    pub indices: Vec<u32>,
    pub lines: Vec<LineVertex>,
}

/// Orbit camera around a target point.
#[derive(Clone, Copy, Debug)]
pub struct OrbitCamera {
    pub target: Point3<f32>,
    pub distance: f32,
    /// Rotation about the vertical axis and elevation, radians.
    pub yaw: f32,
    pub pitch: f32,
}

impl OrbitCamera {
    /// Looking at the face from the front (+z), framing a box of `radius`.
    pub fn framing(center: Point3<f32>, radius: f32) -> Self {
        OrbitCamera {
            target: center,
            distance: 2.6 * radius.max(1e-3),
            yaw: 0.0,
            pitch: 0.0,
        }
    }

    pub fn eye(&self) -> Point3<f32> {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        self.target + Vector3::new(sy * cp, sp, cy * cp) * self.distance
    }

    pub fn orbit(&mut self, dx: f32, dy: f32) {
        self.yaw -= dx * 0.01;
        self.pitch = (self.pitch + dy * 0.01).clamp(-1.5, 1.5);
    }

    /// Moves the target in the view plane by a drag of (dx, dy) pixels in a view `height` tall.
    pub fn pan(&mut self, dx: f32, dy: f32, height: f32) {
        let forward = (self.target - self.eye()).normalize();
        let right = forward.cross(&Vector3::y()).normalize();
        let up = right.cross(&forward);
        let scale = self.distance * 0.8 / height.max(1.0);
        self.target += (-right * dx + up * dy) * scale;
    }

    pub fn zoom(&mut self, factor: f32) {
        self.distance = (self.distance * factor).clamp(0.5, 500.0);
    }

    /// Clip-space transform for wgpu (depth in [0, 1]).
    pub fn view_proj(&self, aspect: f32) -> Matrix4<f32> {
        let view = Matrix4::look_at_rh(&self.eye(), &self.target, &Vector3::y());
        let near = (self.distance * 0.05).max(0.01);
        let proj = Perspective3::new(aspect.max(1e-3), 0.7, near, self.distance * 10.0);
        // nalgebra maps depth to [-1, 1]; wgpu wants [0, 1].
        let mut to_wgpu = Matrix4::identity();
        to_wgpu[(2, 2)] = 0.5;
        to_wgpu[(2, 3)] = 0.5;
        to_wgpu * proj.as_matrix() * view
    }
}

const SCENE_SHADER: &str = r#"
struct U { view_proj: mat4x4<f32>, eye: vec4<f32>, light: vec4<f32> };
@group(0) @binding(0) var<uniform> u: U;

struct SurfOut { @builtin(position) clip: vec4<f32>, @location(0) world: vec3<f32>,
                 @location(1) normal: vec3<f32>, @location(2) color: vec3<f32> };

@vertex fn vs_surface(@location(0) p: vec3<f32>, @location(1) n: vec3<f32>, @location(2) c: vec3<f32>) -> SurfOut {
    var o: SurfOut;
    o.clip = u.view_proj * vec4<f32>(p, 1.0);
    o.world = p; o.normal = n; o.color = c;
    return o;
}

@fragment fn fs_surface(i: SurfOut) -> @location(0) vec4<f32> {
    var n = normalize(i.normal);
    let v = normalize(u.eye.xyz - i.world);
    if (dot(n, v) < 0.0) { n = -n; }
    let l = normalize(u.light.xyz);
    let albedo = pow(i.color, vec3<f32>(2.2));
    let diffuse = max(dot(n, l), 0.0) * 0.75 + max(dot(n, v), 0.0) * 0.2;
    let h = normalize(l + v);
    let spec = pow(max(dot(n, h), 0.0), 40.0) * 0.15;
    let lin = albedo * (0.12 + diffuse) + vec3<f32>(spec);
    return vec4<f32>(pow(lin, vec3<f32>(1.0 / 2.2)), 1.0);
}

struct LineOut { @builtin(position) clip: vec4<f32>, @location(0) color: vec3<f32> };

@vertex fn vs_line(@location(0) p: vec3<f32>, @location(1) c: vec3<f32>) -> LineOut {
    var o: LineOut;
    o.clip = u.view_proj * vec4<f32>(p, 1.0);
    // Pull lines slightly towards the camera so they win against the surface they lie on.
    o.clip.z = o.clip.z - 0.0005 * o.clip.w;
    o.color = c;
    return o;
}

@fragment fn fs_line(i: LineOut) -> @location(0) vec4<f32> {
    return vec4<f32>(i.color, 1.0);
}
"#;

const BLIT_SHADER: &str = r#"
@group(0) @binding(0) var t: texture_2d<f32>;
@group(0) @binding(1) var s: sampler;
struct Out { @builtin(position) clip: vec4<f32>, @location(0) uv: vec2<f32> };
@vertex fn vs(@builtin(vertex_index) i: u32) -> Out {
    let xy = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    var o: Out;
    o.clip = vec4<f32>(xy * 2.0 - 1.0, 0.0, 1.0);
    o.uv = vec2<f32>(xy.x, 1.0 - xy.y);
    return o;
}
@fragment fn fs(i: Out) -> @location(0) vec4<f32> { return textureSample(t, s, i.uv); }
"#;

const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// GPU objects shared by all viewport paints (stored in egui_wgpu's callback resources).
pub struct ViewportResources {
    surface: wgpu::RenderPipeline,
    lines: wgpu::RenderPipeline,
    blit: wgpu::RenderPipeline,
    uniforms: wgpu::Buffer,
    uniform_group: wgpu::BindGroup,
    blit_layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
    target: Option<Target>,
    /// (vertex buffer, index buffer, index count), (line buffer, line vertex count).
    mesh: Option<(wgpu::Buffer, wgpu::Buffer, u32)>,
    line_buffer: Option<(wgpu::Buffer, u32)>,
    /// The scene now on the GPU (held, so its address cannot be reused by another).
    uploaded_scene: Option<Arc<Scene>>,
}

struct Target {
    size: [u32; 2],
    color: wgpu::TextureView,
    depth: wgpu::TextureView,
    blit_group: wgpu::BindGroup,
}

impl ViewportResources {
    /// Registers the viewport's GPU objects with the app's wgpu renderer.
    pub fn install(render_state: &egui_wgpu::RenderState) {
        let res = Self::new(&render_state.device, render_state.target_format);
        render_state.renderer.write().callback_resources.insert(res);
    }

    fn new(device: &wgpu::Device, target_format: wgpu::TextureFormat) -> Self {
        let scene = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("facesim scene"),
            source: wgpu::ShaderSource::Wgsl(SCENE_SHADER.into()),
        });
        let blit_shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("facesim blit"),
            source: wgpu::ShaderSource::Wgsl(BLIT_SHADER.into()),
        });
        let uniform_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("facesim uniforms"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("facesim uniforms"),
            size: std::mem::size_of::<Uniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let uniform_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("facesim uniforms"),
            layout: &uniform_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: uniforms.as_entire_binding(),
            }],
        });
        let scene_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("facesim scene"),
            bind_group_layouts: &[Some(&uniform_layout)],
            immediate_size: 0,
        });
        let depth = |write: bool| {
            Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(write),
                depth_compare: Some(wgpu::CompareFunction::LessEqual),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState::default(),
            })
        };
        let pipeline = |label: &str,
                        vs: &str,
                        fs: &str,
                        layout: wgpu::VertexBufferLayout<'_>,
                        topology: wgpu::PrimitiveTopology| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(&scene_layout),
                vertex: wgpu::VertexState {
                    module: &scene,
                    entry_point: Some(vs),
                    compilation_options: Default::default(),
                    buffers: &[Some(layout)],
                },
                primitive: wgpu::PrimitiveState {
                    topology,
                    ..Default::default()
                },
                depth_stencil: depth(true),
                multisample: wgpu::MultisampleState::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &scene,
                    entry_point: Some(fs),
                    compilation_options: Default::default(),
                    targets: &[Some(COLOR_FORMAT.into())],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let surface = pipeline(
            "facesim surface",
            "vs_surface",
            "fs_surface",
            wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<SurfaceVertex>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3, 2 => Float32x3],
            },
            wgpu::PrimitiveTopology::TriangleList,
        );
        let lines = pipeline(
            "facesim lines",
            "vs_line",
            "fs_line",
            wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<LineVertex>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3],
            },
            wgpu::PrimitiveTopology::LineList,
        );
        let blit_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("facesim blit"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let blit_pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("facesim blit"),
            bind_group_layouts: &[Some(&blit_layout)],
            immediate_size: 0,
        });
        let blit = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("facesim blit"),
            layout: Some(&blit_pipeline_layout),
            vertex: wgpu::VertexState {
                module: &blit_shader,
                entry_point: Some("vs"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &blit_shader,
                entry_point: Some("fs"),
                compilation_options: Default::default(),
                targets: &[Some(target_format.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("facesim blit"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        ViewportResources {
            surface,
            lines,
            blit,
            uniforms,
            uniform_group,
            blit_layout,
            sampler,
            target: None,
            mesh: None,
            line_buffer: None,
            uploaded_scene: None,
        }
    }

    fn ensure_target(&mut self, device: &wgpu::Device, size: [u32; 2]) {
        if self.target.as_ref().is_some_and(|t| t.size == size) {
            return;
        }
        let texture = |format, usage, label| {
            device
                .create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size: wgpu::Extent3d {
                        width: size[0],
                        height: size[1],
                        depth_or_array_layers: 1,
                    },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                })
                .create_view(&wgpu::TextureViewDescriptor::default())
        };
        let color = texture(
            COLOR_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            "facesim viewport colour",
        );
        let depth = texture(
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
            "facesim viewport depth",
        );
        let blit_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("facesim blit"),
            layout: &self.blit_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&color),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::Sampler(&self.sampler),
                },
            ],
        });
        self.target = Some(Target {
            size,
            color,
            depth,
            blit_group,
        });
    }
}

/// One paint of the viewport.
pub struct ViewportCallback {
    pub scene: Arc<Scene>,
    pub camera: OrbitCamera,
    pub size_px: [u32; 2],
    pub background: [f64; 3],
}

impl egui_wgpu::CallbackTrait for ViewportCallback {
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        _screen: &egui_wgpu::ScreenDescriptor,
        encoder: &mut wgpu::CommandEncoder,
        resources: &mut egui_wgpu::CallbackResources,
    ) -> Vec<wgpu::CommandBuffer> {
        let Some(res) = resources.get_mut::<ViewportResources>() else {
            return Vec::new();
        };
        let size = [self.size_px[0].max(1), self.size_px[1].max(1)];
        res.ensure_target(device, size);
        let eye = self.camera.eye();
        let light = self.camera.eye() - self.camera.target
            + Vector3::new(0.3, 0.6, 0.0) * self.camera.distance;
        let u = Uniforms {
            view_proj: self
                .camera
                .view_proj(size[0] as f32 / size[1] as f32)
                .into(),
            eye: [eye.x, eye.y, eye.z, 1.0],
            light: [light.x, light.y, light.z, 0.0],
        };
        queue.write_buffer(&res.uniforms, 0, bytemuck::bytes_of(&u));
        // Upload when the scene is not the one on the GPU (UI passes may run without a paint
        // in between, so a per-pass "changed" flag would miss updates).
        if !res
            .uploaded_scene
            .as_ref()
            .is_some_and(|s| Arc::ptr_eq(s, &self.scene))
        {
            res.uploaded_scene = Some(self.scene.clone());
            let s = &self.scene;
            res.mesh = (!s.indices.is_empty()).then(|| {
                let v = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("facesim surface"),
                    contents: bytemuck::cast_slice(&s.vertices),
                    usage: wgpu::BufferUsages::VERTEX,
                });
                let i = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("facesim surface indices"),
                    contents: bytemuck::cast_slice(&s.indices),
                    usage: wgpu::BufferUsages::INDEX,
                });
                (v, i, s.indices.len() as u32)
            });
            res.line_buffer = (!s.lines.is_empty()).then(|| {
                let b = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("facesim lines"),
                    contents: bytemuck::cast_slice(&s.lines),
                    usage: wgpu::BufferUsages::VERTEX,
                });
                (b, s.lines.len() as u32)
            });
        }
        let target = res.target.as_ref().expect("ensured above");
        let [r, g, b] = self.background;
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("facesim viewport"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &target.color,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color { r, g, b, a: 1.0 }),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &target.depth,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_bind_group(0, &res.uniform_group, &[]);
        if let Some((v, i, n)) = &res.mesh {
            pass.set_pipeline(&res.surface);
            pass.set_vertex_buffer(0, v.slice(..));
            pass.set_index_buffer(i.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..*n, 0, 0..1);
        }
        if let Some((b, n)) = &res.line_buffer {
            pass.set_pipeline(&res.lines);
            pass.set_vertex_buffer(0, b.slice(..));
            pass.draw(0..*n, 0..1);
        }
        Vec::new()
    }

    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        render_pass: &mut wgpu::RenderPass<'static>,
        resources: &egui_wgpu::CallbackResources,
    ) {
        let Some(res) = resources.get::<ViewportResources>() else {
            return;
        };
        let Some(target) = &res.target else { return };
        render_pass.set_pipeline(&res.blit);
        render_pass.set_bind_group(0, &target.blit_group, &[]);
        render_pass.draw(0..3, 0..1);
    }
}
