//! The scene as the GPU sees it: the `SceneBlock` storage buffer (glsl/include/scene.glsl),
//! the density volume and the majorant grid, shared by every solver.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::gpu::{Buffer, Gpu, Image3d, Pass, VolumeFormat};
use crate::scene::bvh::{BvhNode, GpuTriangle};
use crate::scene::{CameraKind, Density, Emission, Light, Material, Scene, MAX_MATERIALS};

use crate::solvers::interface::SolverError;
// The specialisation ids and what a render models are the interface's; kernels name them here,
// beside the scene block they describe.
pub use crate::solvers::interface::modelled::*;

/// Header of `SceneBlock` (std430; vec4-sized members only, so Rust and GLSL agree).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct SceneHeader {
    pub bounds_min: [f32; 4],
    pub bounds_max: [f32; 4],
    pub sphere: [f32; 4],
    pub grid_dims: [u32; 4],
    pub maj_dims: [u32; 4],
    pub cam_origin: [f32; 4],
    pub cam_forward: [f32; 4],
    pub cam_right: [f32; 4],
    pub cam_up: [f32; 4],
    pub image: [u32; 4],
    /// The emission grid's voxels xyz over the medium's box, w its channels (1 or 3; 0: the
    /// scene has no emission grid): [`emission_planes`].
    pub emission_dims: [u32; 4],
    /// The material table, the one route by which a medium's coefficients reach a kernel
    /// (glsl/include/scene_block.glsl): the objects' materials
    /// ([`crate::scene::Object::materials`]; a triangle's `v0[3]` names its own), the medium's
    /// as material 0 in every scene, zeros past the last.
    pub materials: [GpuMaterial; MAX_MATERIALS],
    /// The density fields the materials name (`GpuMaterial::ior[1]`): the medium's as field 0
    /// in every scene, zeros past the last.
    pub fields: [GpuField; MAX_MATERIALS],
}

/// One entry of `SceneHeader::fields` (scene.glsl `DensityField`): a density kind over a box,
/// a grid's place in the density atlas and the majorant buffer.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuField {
    /// xyz: the box; w: the density kind (0 constant, 1 sphere, 2 grid) as u32 bits.
    pub bounds_min: [f32; 4],
    /// xyz: the box; w: the grid's first z slice in the density atlas, as u32 bits.
    pub bounds_max: [f32; 4],
    /// Sphere density: centre xyz, radius w.
    pub sphere: [f32; 4],
    /// Grid voxels xyz; w: the grid's first cell in the majorant buffer.
    pub grid_dims: [u32; 4],
    /// Majorant cells xyz; w: voxels per cell edge.
    pub maj_dims: [u32; 4],
}

/// One entry of `SceneHeader::materials` (scene.glsl `ObjectMaterial`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuMaterial {
    /// rgb extinction scale, 1/unit; w = max over channels.
    pub sigma_t: [f32; 4],
    /// rgb albedo; w = g.
    pub albedo: [f32; 4],
    /// x = ior inside relative to the vacuum outside; y = its density field (u32 bits).
    pub ior: [f32; 4],
    /// rgb: emitted radiance Le, W/(m^2 sr), or the emission grid's scale; w: 1 = times the
    /// emission grid.
    pub emission: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuLight {
    pub pos_kind: [f32; 4],
    pub value: [f32; 4],
}

pub const LIGHT_POINT: f32 = 0.0;
pub const LIGHT_DIRECTIONAL: f32 = 1.0;
pub const LIGHT_ENVIRONMENT: f32 = 2.0;

/// The binding of the emission grid (glsl/include/scene.glsl `emis`) in kernels that define
/// EMISSION_BINDING: past every kernel's own bindings.
pub const EMISSION_BINDING: u32 = 15;

/// Bindings of the mesh's BVH nodes and triangles in kernels that include mesh.glsl.
pub const MESH_NODES_BINDING: u32 = 6;
pub const MESH_TRIS_BINDING: u32 = 7;

/// Scene data resident on the device.
pub struct GpuScene {
    pub block: Buffer,
    pub density: Image3d,
    pub majorant: Buffer,
    /// The [[object]]'s BVH nodes and triangles (src/scene/bvh.rs layout); one-element
    /// placeholders without a mesh, bound because mesh.glsl's layout declares them.
    pub mesh_nodes: Buffer,
    pub mesh_tris: Buffer,
    /// The emission grid's planes ([`emission_planes`]); a one-float placeholder without one,
    /// bound because kernels that collect emission declare it.
    pub emission: Buffer,
    pub modelled: Modelled,
    pub bytes: u64,
}

fn v4(v: Vec3, w: f32) -> [f32; 4] {
    [v.x, v.y, v.z, w]
}

/// Voxels per majorant cell edge: 16 gives 4^3 cells on a 64^3 grid. pbrt-v4 uses 16^3 cells
/// whatever the grid, Mitsuba 3 one global majorant by default. A coarser majorant takes more
/// null collisions but crosses fewer cells, and on llvmpipe a cell crossing (the DDA step) costs
/// more than a null collision's density lookup. `path` at 128 x 128, cell edge 4 / 8 / 16 / 32,
/// time and relMSE against an 8192-spp reference: the cloud 7.57 / 6.22 / 5.81 / 5.88 s at
/// relMSE 2.47 / 2.46 / 2.33 / 2.28e-3 (time x relMSE 1.38x better at 16); point-light-in-cloud
/// 10.6 / 8.44 / 7.91 / 7.68 s at 1.48 / 1.50 / 1.54 / 1.59e-3 (1.29x at 16).
pub const MAJORANT_CELL: u32 = 16;

pub fn majorant_dims(dims: [u32; 3], cell: u32) -> [u32; 3] {
    [dims[0].div_ceil(cell), dims[1].div_ceil(cell), dims[2].div_ceil(cell)]
}

/// Per-cell maximum density over every voxel that trilinear interpolation can reach from a
/// point inside the cell, padded by one voxel against rounding at cell faces. A majorant
/// that is too low biases delta tracking; one that is too high only costs time.
pub fn majorant_grid(dims: [u32; 3], data: &[f32], m: [u32; 3]) -> Vec<f32> {
    let range = |c: u32, n: u32, mcount: u32| -> (u32, u32) {
        let lo = (c as f64 * n as f64 / mcount as f64 - 0.5).floor() as i64 - 1;
        let hi = ((c + 1) as f64 * n as f64 / mcount as f64 - 0.5).floor() as i64 + 2;
        (lo.clamp(0, n as i64 - 1) as u32, hi.clamp(0, n as i64 - 1) as u32)
    };
    let mut out = vec![0f32; (m[0] * m[1] * m[2]) as usize];
    for cz in 0..m[2] {
        let (z0, z1) = range(cz, dims[2], m[2]);
        for cy in 0..m[1] {
            let (y0, y1) = range(cy, dims[1], m[1]);
            for cx in 0..m[0] {
                let (x0, x1) = range(cx, dims[0], m[0]);
                let mut mx = 0f32;
                for z in z0..=z1 {
                    for y in y0..=y1 {
                        let row = ((z * dims[1] + y) * dims[0]) as usize;
                        for x in x0..=x1 {
                            mx = mx.max(data[row + x as usize]);
                        }
                    }
                }
                out[(cx + m[0] * (cy + m[1] * cz)) as usize] = mx;
            }
        }
    }
    out
}

/// The header and lights as bytes; pure, so tests can check the layout without a device.
pub fn scene_block(scene: &Scene) -> (SceneHeader, Vec<GpuLight>) {
    scene_block_with(scene, MAJORANT_CELL)
}

/// [`scene_block`] with majorant cells of `cell` voxels on an edge (`path.majorant_cell`).
pub fn scene_block_with(scene: &Scene, cell: u32) -> (SceneHeader, Vec<GpuLight>) {
    let m = &scene.medium;
    let cam = &scene.camera;
    let (right, up, forward) = cam.basis();
    let (cam_kind, k) = match cam.kind {
        CameraKind::Perspective { fov_deg } => (0.0, (fov_deg.to_radians() * 0.5).tan()),
        CameraKind::Orthographic { extent } => (1.0, extent * 0.5),
    };
    let (sphere, grid_dims, maj_dims) = match &m.density {
        Density::Constant => ([0.0; 4], [1, 1, 1, 0], [1, 1, 1, 1]),
        Density::Sphere { center, radius } => (v4(*center, *radius), [1, 1, 1, 0], [1, 1, 1, 1]),
        Density::Grid(g) => {
            let md = majorant_dims(g.dims, cell);
            ([0.0; 4], [g.dims[0], g.dims[1], g.dims[2], 0], [md[0], md[1], md[2], cell])
        }
    };
    let lights: Vec<GpuLight> = scene
        .lights
        .iter()
        .map(|l| match l {
            Light::Point { position, intensity } => {
                GpuLight { pos_kind: v4(*position, LIGHT_POINT), value: v4(*intensity, 0.0) }
            }
            Light::Directional { direction, irradiance } => {
                GpuLight { pos_kind: v4(direction.normalize(), LIGHT_DIRECTIONAL), value: v4(*irradiance, 0.0) }
            }
            Light::Environment { radiance } => {
                GpuLight { pos_kind: [0.0, 0.0, 0.0, LIGHT_ENVIRONMENT], value: v4(*radiance, 0.0) }
            }
        })
        .collect();
    let atlas = density_atlas(scene, cell, false);
    let mut header = SceneHeader {
        bounds_min: v4(m.bounds_min, 0.0),
        bounds_max: v4(m.bounds_max, 0.0),
        sphere,
        grid_dims,
        maj_dims,
        cam_origin: v4(cam.origin, cam_kind),
        cam_forward: v4(forward, k),
        cam_right: v4(right, 0.0),
        cam_up: v4(up, 0.0),
        image: [scene.render.width, scene.render.height, lights.len() as u32, 0],
        emission_dims: match &m.emission {
            Emission::Grid(e) => {
                let d = e.dims();
                [d[0], d[1], d[2], e.planes.len() as u32]
            }
            _ => [0; 4],
        },
        materials: gpu_materials(scene),
        fields: atlas.fields,
    };
    if atlas.field_count > 1 {
        // Several fields: no one sphere bounds the media (pixel_misses_medium uses the box).
        header.sphere = [0.0; 4];
    }
    (header, lights)
}

/// The scene block's material table: the objects' materials, or the v1 medium's alone.
fn gpu_materials(scene: &Scene) -> [GpuMaterial; MAX_MATERIALS] {
    let mut table = [GpuMaterial::zeroed(); MAX_MATERIALS];
    match &scene.object {
        Some(o) => {
            for (slot, x) in table.iter_mut().zip(&o.materials) {
                *slot = gpu_material(x);
            }
        }
        None => table[0] = gpu_material(&Material::of(&scene.medium, 1.0, 0)),
    }
    table
}

fn gpu_material(x: &Material) -> GpuMaterial {
    GpuMaterial {
        sigma_t: v4(x.sigma_t, x.sigma_t.max_element()),
        albedo: v4(x.albedo, x.g),
        ior: [x.ior, f32::from_bits(x.field as u32), 0.0, 0.0],
        emission: v4(x.emission, if x.emission_grid { 1.0 } else { 0.0 }),
    }
}

/// The emission grid on the device: its planes one after the other (one per channel, x
/// fastest), or nothing when Le does not vary.
pub fn emission_planes(scene: &Scene) -> Vec<f32> {
    match &scene.medium.emission {
        Emission::Grid(e) => e.planes.iter().flat_map(|p| p.data.iter().copied()).collect(),
        _ => Vec::new(),
    }
}

/// A scene block that holds a material table and nothing else (no box, camera or light), for
/// kernels that read only the table run without a scene: the lattice's test bench
/// ([`crate::solvers::parts::lattice::diffuse_impulse`]).
pub fn table_block(materials: &[Material]) -> SceneHeader {
    let mut header = SceneHeader::zeroed();
    for (slot, x) in header.materials.iter_mut().zip(materials) {
        *slot = gpu_material(x);
    }
    header
}

/// The density fields on the device: every grid in one 3D image (the atlas: grids stacked
/// along z, each padded to the widest in x and y; one grid is the image itself) and its
/// majorant cells in one buffer, with each field's place.
pub struct DensityAtlas {
    pub dims: [u32; 3],
    /// Empty when no field is a grid, or built without data.
    pub data: Vec<f32>,
    pub majorant: Vec<f32>,
    /// Majorant cells of every grid (the length of `majorant` when built with data); 0 when
    /// no field is a grid.
    pub majorant_cells: u32,
    pub fields: [GpuField; MAX_MATERIALS],
    /// How many of `fields` are the scene's.
    pub field_count: usize,
}

/// Build the [`DensityAtlas`] with majorant cells of `cell` voxels on an edge. A grid shared by
/// several fields is stored once. Without `with_data`, only the places (`fields`, `dims`): the
/// voxels and majorant cells are not copied.
pub fn density_atlas(scene: &Scene, cell: u32, with_data: bool) -> DensityAtlas {
    let fields = scene.fields();
    let grids: Vec<&crate::scene::Grid> = fields
        .iter()
        .filter_map(|f| match f.density {
            Density::Grid(g) => Some(g),
            _ => None,
        })
        .collect();
    let (wx, wy) = grids.iter().fold((0, 0), |(x, y), g| (x.max(g.dims[0]), y.max(g.dims[1])));
    let mut placed: Vec<(&crate::scene::Grid, u32, u32)> = Vec::new();
    let (mut depth, mut data, mut majorant) = (0u32, Vec::new(), Vec::new());
    let mut majorant_cells = 0u32;
    let mut table = [GpuField::zeroed(); MAX_MATERIALS];
    for (slot, f) in table.iter_mut().zip(&fields) {
        let mut e = GpuField {
            bounds_min: v4(f.bounds_min, f32::from_bits(0)),
            bounds_max: v4(f.bounds_max, f32::from_bits(0)),
            sphere: [0.0; 4],
            grid_dims: [1, 1, 1, 0],
            maj_dims: [1, 1, 1, 1],
        };
        match f.density {
            Density::Constant => {}
            Density::Sphere { center, radius } => {
                e.bounds_min[3] = f32::from_bits(1);
                e.sphere = v4(*center, *radius);
            }
            Density::Grid(g) => {
                let md = majorant_dims(g.dims, cell);
                let (z, maj) = match placed.iter().find(|(p, _, _)| **p == *g) {
                    Some(&(_, z, maj)) => (z, maj),
                    None => {
                        let at = (depth, majorant_cells);
                        let [nx, ny, nz] = g.dims;
                        majorant_cells += md[0] * md[1] * md[2];
                        depth += nz;
                        if with_data {
                            if nx == wx && ny == wy {
                                data.extend_from_slice(&g.data);
                            } else {
                                // Padded rows and slices: voxel (x, y, z) at (x, y, first + z).
                                let mut padded = vec![0f32; (wx * wy * nz) as usize];
                                for k in 0..nz {
                                    for j in 0..ny {
                                        let src = ((k * ny + j) * nx) as usize;
                                        let dst = ((k * wy + j) * wx) as usize;
                                        padded[dst..dst + nx as usize].copy_from_slice(&g.data[src..src + nx as usize]);
                                    }
                                }
                                data.extend_from_slice(&padded);
                            }
                            majorant.extend(majorant_grid(g.dims, &g.data, md));
                        }
                        placed.push((g, at.0, at.1));
                        at
                    }
                };
                e.bounds_min[3] = f32::from_bits(2);
                e.bounds_max[3] = f32::from_bits(z);
                e.grid_dims = [g.dims[0], g.dims[1], g.dims[2], maj];
                e.maj_dims = [md[0], md[1], md[2], cell];
            }
        }
        *slot = e;
    }
    let dims = if grids.len() == 1 { grids[0].dims } else { [wx.max(1), wy.max(1), depth.max(1)] };
    DensityAtlas { dims, data, majorant, majorant_cells, fields: table, field_count: fields.len() }
}

/// Channels a solver's grids carry: one when the medium (`chromatic`: [`modelled`]'s) and every
/// light are grey (model only what the scene requires), else three.
pub fn channels(scene: &Scene, chromatic: bool) -> u32 {
    let grey_lights = scene.lights.iter().all(|l| crate::scene::is_grey(l.colour()));
    if chromatic || !grey_lights {
        3
    } else {
        1
    }
}

/// Bytes the scene occupies on the device (block, density volume, majorant grid).
pub fn scene_bytes(scene: &Scene) -> u64 {
    scene_bytes_with(scene, MAJORANT_CELL)
}

/// [`scene_bytes`] with majorant cells of `cell` voxels on an edge (`path.majorant_cell`).
pub fn scene_bytes_with(scene: &Scene, cell: u32) -> u64 {
    let block = (std::mem::size_of::<SceneHeader>() + scene.lights.len() * std::mem::size_of::<GpuLight>()) as u64;
    // Without an object: the one-element placeholders `upload_with` binds.
    let placeholders = (std::mem::size_of::<BvhNode>() + std::mem::size_of::<GpuTriangle>()) as u64;
    let mesh = scene.object.as_ref().map_or(placeholders, |o| o.bvh.bytes());
    // The emission grid, or its one-float placeholder.
    let emission = scene.medium.emission.grid().map_or(4, |e| e.bytes());
    let block = block + mesh + emission;
    let atlas = density_atlas(scene, cell, false);
    if atlas.majorant_cells == 0 {
        block + 4 + 4
    } else {
        block + atlas.dims.iter().map(|d| *d as u64).product::<u64>() * 4 + atlas.majorant_cells as u64 * 4
    }
}

impl GpuScene {
    /// Bind the scene block, density volume and majorant grid at bindings 0, 1, 2, where every
    /// kernel that includes scene.glsl declares them.
    pub fn bind(&self, pass: Pass) -> Pass {
        pass.read(0, &self.block).read(1, &self.density).read(2, &self.majorant)
    }

    /// The emission grid at [`EMISSION_BINDING`], for kernels that collect emission.
    pub fn bind_emission(&self, pass: Pass) -> Pass {
        pass.read(EMISSION_BINDING, &self.emission)
    }

    /// [`GpuScene::bind`] and the mesh's BVH at [`MESH_NODES_BINDING`], [`MESH_TRIS_BINDING`].
    pub fn bind_mesh(&self, pass: Pass) -> Pass {
        self.bind(pass).read(MESH_NODES_BINDING, &self.mesh_nodes).read(MESH_TRIS_BINDING, &self.mesh_tris)
    }

    /// Upload for a solver that does not trace meshes: a scene with an [[object]] is refused
    /// in one line, never rendered as if its medium filled the box. The command line refuses
    /// such scenes earlier, before opening the device (`Solver::scene_refusal`); this is the
    /// library's guard for callers that go straight to `Solver::render`.
    pub fn upload(gpu: &Gpu, scene: &Scene, force_full: bool) -> Result<GpuScene, SolverError> {
        if let Some(o) = &scene.object {
            return Err(SolverError::Unsupported(format!(
                "{}: only path, single and lbl render [[object]] meshes so far (the object is {}); use --solver path, single or lbl, or a v1 [medium]",
                scene.source.display(),
                o.describe()
            )));
        }
        Self::upload_with(gpu, scene, force_full, MAJORANT_CELL)
    }

    /// [`GpuScene::upload`] with majorant cells of `cell` voxels on an edge (`path.majorant_cell`;
    /// only the path kernels read the majorant).
    pub fn upload_with(gpu: &Gpu, scene: &Scene, force_full: bool, cell: u32) -> Result<GpuScene, SolverError> {
        let (header, lights) = scene_block_with(scene, cell);
        let mut bytes = bytemuck::bytes_of(&header).to_vec();
        bytes.extend_from_slice(bytemuck::cast_slice(&lights));
        let block = gpu.buffer("scene block", bytes.len() as u64)?;
        gpu.write_buffer(&block, 0, &bytes)?;
        let atlas = density_atlas(scene, cell, true);
        let maxd = gpu.info().max_image_dimension_3d;
        if atlas.field_count > 1 && atlas.dims.iter().any(|d| *d > maxd) {
            return Err(SolverError::Unsupported(format!(
                "{}: the objects' density grids stack to {} x {} x {} voxels on the device, beyond its \
                    maxImageDimension3D {maxd}; give objects the same grid (one density table), or use fewer or \
                    smaller grids",
                scene.source.display(),
                atlas.dims[0],
                atlas.dims[1],
                atlas.dims[2]
            )));
        }
        let (density, majorant) = if !atlas.data.is_empty() {
            (
                gpu.image3d_with("density grid", atlas.dims, VolumeFormat::R32F, &atlas.data)?,
                gpu.buffer_with("majorant grid", &atlas.majorant)?,
            )
        } else {
            // Kernels specialised for analytic densities never read these; they are bound
            // because the shared layout declares them.
            (
                gpu.image3d_with("density (unused)", [1, 1, 1], VolumeFormat::R32F, &[0.0])?,
                gpu.buffer_with("majorant (unused)", &[0f32])?,
            )
        };
        let (mesh_nodes, mesh_tris) = match &scene.object {
            Some(o) => {
                (gpu.buffer_with("mesh BVH nodes", &o.bvh.nodes)?, gpu.buffer_with("mesh triangles", &o.bvh.triangles)?)
            }
            None => (
                gpu.buffer_with("mesh BVH nodes (unused)", &[BvhNode::zeroed()])?,
                gpu.buffer_with("mesh triangles (unused)", &[GpuTriangle::zeroed()])?,
            ),
        };
        let planes = emission_planes(scene);
        let emission = if planes.is_empty() {
            gpu.buffer_with("emission grid (unused)", &[0f32])?
        } else {
            gpu.buffer_with("emission grid", &planes)?
        };
        Ok(GpuScene {
            block,
            density,
            majorant,
            mesh_nodes,
            mesh_tris,
            emission,
            modelled: modelled(scene, force_full),
            bytes: scene_bytes_with(scene, cell),
        })
    }
}
