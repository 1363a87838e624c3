//! The image of the network: the particles' radiance toward the camera gathered and splatted
//! front to back with the medium's transmittance (illumination networks 3.3, its last paragraph).

use super::*;

/// Pixels along a side of the splats' screen tiles (glsl/networks/splat.comp).
pub const SPLAT_TILE: u32 = 16;

/// The particles nearest the camera first (distance from a perspective camera, depth along an
/// orthographic one's axis; ties by index): splat.comp composites in this order.
pub fn splat_order(camera: &crate::scene::Camera, positions: &[Vec3]) -> Vec<u32> {
    let origin = camera.origin;
    let axis = match camera.kind {
        crate::scene::CameraKind::Orthographic { .. } => Some(camera.basis().2),
        crate::scene::CameraKind::Perspective { .. } => None,
    };
    let key = |x: &Vec3| match axis {
        Some(a) => (*x - origin).dot(a),
        None => (*x - origin).length(),
    };
    let keys: Vec<f32> = positions.iter().map(key).collect();
    let mut order: Vec<u32> = (0..positions.len() as u32).collect();
    order.sort_by(|a, b| keys[*a as usize].total_cmp(&keys[*b as usize]).then(a.cmp(b)));
    order
}

/// The splats' screen tiles: which particles each tile of [`SPLAT_TILE`]^2 pixels composites.
/// splat.comp's pixel keeps the particles within three footprint widths of its centre's camera
/// ray, nearest first; it used to test every particle, N per pixel (4096 particles at 512^2:
/// 20 s of lavapipe, half the render). A tile's list holds, in the same order, every particle
/// whose reach could touch a ray through one of its pixel centres (a superset: the sphere of
/// the reach, grown by 0.1%, projected to its exact bounding box on the image and widened by a
/// pixel), so each pixel keeps exactly the particles, in exactly the order, that the test of
/// all of them kept: the same image, bit for bit. `tile` = the image's larger side gives one
/// tile holding every particle, the general kernel (`--model-all`).
pub struct SplatTiles {
    pub tile: u32,
    pub tiles_x: u32,
    /// Per tile, where its list starts in `items`; one more entry ends the last.
    pub starts: Vec<u32>,
    pub items: Vec<u32>,
}

impl SplatTiles {
    /// The tiles a render of `net` at `camera` and `size` splats with: its particles in
    /// [`splat_order`], a reach of three footprints (`footprint` particle radii), tiles of
    /// `tile` pixels a side (None: [`SPLAT_TILE`], or one tile of every particle with
    /// `force_full`, `--model-all`). [`Illumination::image`] and the memory estimate both take
    /// them from here.
    pub fn of(
        camera: &crate::scene::Camera,
        size: [u32; 2],
        net: &Network,
        footprint: f32,
        tile: Option<u32>,
        force_full: bool,
    ) -> SplatTiles {
        let tile = tile.unwrap_or(if force_full { size[0].max(size[1]) } else { SPLAT_TILE }).max(1);
        let positions = &net.particles.positions;
        let reach = 3.0 * splat_width(net, footprint) as f64;
        SplatTiles::new(camera, size, positions, &splat_order(camera, positions), reach, tile)
    }

    /// Bin the particles `order` lists (nearest the camera first) for `camera` and an image of
    /// `size` pixels, `reach` (scene units) the farthest a ray is from a particle whose splat
    /// it composites.
    pub fn new(
        camera: &crate::scene::Camera,
        size: [u32; 2],
        positions: &[Vec3],
        order: &[u32],
        reach: f64,
        tile: u32,
    ) -> SplatTiles {
        let [w, h] = size;
        let (tiles_x, tiles_y) = (w.div_ceil(tile), h.div_ceil(tile));
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); (tiles_x * tiles_y) as usize];
        let (right, up, forward) = camera.basis();
        let (right, up, forward) = (right.as_dvec3(), up.as_dvec3(), forward.as_dvec3());
        let origin = camera.origin.as_dvec3();
        let aspect = h as f64 / w as f64;
        // The reach grown for the f32 rounding of the device's rays and distances.
        let r = reach * 1.001 + 1e-6;
        for &q in order {
            let v = positions[q as usize].as_dvec3() - origin;
            let c = glam::DVec3::new(v.dot(right), v.dot(up), v.dot(forward));
            // The range of ndc (x right, y up) whose rays come within r of the particle: None
            // where it may be any.
            let range = match camera.kind {
                crate::scene::CameraKind::Perspective { fov_deg } => {
                    let k = ((fov_deg as f64).to_radians() * 0.5).tan();
                    if c.z < -r {
                        // Wholly behind the eye: a ray's nearest point to it is behind too.
                        continue;
                    }
                    if c.z <= r {
                        // The reach's sphere reaches the camera's plane: any ray in front may pass.
                        None
                    } else {
                        // Lines x = m z through the eye tangent to the reach's circle (cx, cz, r)
                        // in the xz plane (and yz): x / z over the sphere spans their slopes.
                        let slopes = |a: f64| {
                            let root = r * (a * a + c.z * c.z - r * r).sqrt();
                            let den = c.z * c.z - r * r;
                            ((a * c.z - root) / den, (a * c.z + root) / den)
                        };
                        let (x0, x1) = slopes(c.x);
                        let (y0, y1) = slopes(c.y);
                        Some([x0 / k, x1 / k, y0 / (k * aspect), y1 / (k * aspect)])
                    }
                }
                crate::scene::CameraKind::Orthographic { extent } => {
                    let k = extent as f64 * 0.5;
                    // Behind the image plane: no ray's t is positive (with room for rounding).
                    if c.z < -r {
                        continue;
                    }
                    Some([(c.x - r) / k, (c.x + r) / k, (c.y - r) / (k * aspect), (c.y + r) / (k * aspect)])
                }
            };
            // Pixel px's centre is at ndc x = (px + 0.5) / w * 2 - 1, y = 1 - (py + 0.5) / h * 2.
            let (px, py) = match range {
                None => ((0, w as i64 - 1), (0, h as i64 - 1)),
                Some([x0, x1, y0, y1]) => {
                    let col = |x: f64| (x + 1.0) * 0.5 * w as f64 - 0.5;
                    let row = |y: f64| (1.0 - y) * 0.5 * h as f64 - 0.5;
                    let lo = |p: f64| (p.floor() as i64 - 1).max(0);
                    let hi = |p: f64, n: u32| (p.ceil() as i64 + 1).min(n as i64 - 1);
                    ((lo(col(x0)), hi(col(x1), w)), (lo(row(y1)), hi(row(y0), h)))
                }
            };
            if px.0 > px.1 || py.0 > py.1 {
                continue;
            }
            for ty in py.0 / tile as i64..=py.1 / tile as i64 {
                for tx in px.0 / tile as i64..=px.1 / tile as i64 {
                    lists[(ty * tiles_x as i64 + tx) as usize].push(q);
                }
            }
        }
        let mut starts = Vec::with_capacity(lists.len() + 1);
        let mut items = Vec::with_capacity(lists.iter().map(Vec::len).sum());
        for l in &lists {
            starts.push(items.len() as u32);
            items.extend_from_slice(l);
        }
        starts.push(items.len() as u32);
        SplatTiles { tile, tiles_x, starts, items }
    }
}

/// The image of the splats: pixels, and how many splats were left out where more than a
/// pixel holds overlapped it (the farthest go).
pub struct Splatted {
    pub image: crate::output::Image,
    pub dropped: u64,
    /// Pixels that came out non-finite and were set to 0.
    pub nonfinite: u32,
}

/// A splat's footprint width s (scene units): `footprint` particle radii (splat.comp's
/// `width`, whose three widths are a splat's reach).
fn splat_width(net: &Network, footprint: f32) -> f32 {
    net.particle_radius() as f32 * footprint
}

impl Illumination {
    /// The image (paper 3.3's last paragraph) with the scene's camera: each particle's
    /// radiance toward the camera (glsl/networks/gather.comp), then the particles splatted
    /// front to back with alpha blending (glsl/networks/splat.comp), Gaussian footprints of the
    /// particle's radius b carrying its extinction cross-section sigma_t m.
    /// `width`: the footprint's width in particle radii. `medium_step`: > 0 scales each
    /// camera ray's splats so that their optical depths sum to the medium's along the ray
    /// (marched in steps of it, scene units; `networks.transmittance = medium`), 0 keeps the
    /// splats' own (the paper's).
    pub fn image(&self, gpu: &Gpu, net: &Network, width: f32, medium_step: f32) -> Result<Splatted, SolverError> {
        self.image_tiled(gpu, net, width, medium_step, None)
    }

    /// [`Illumination::image`] with screen tiles of `tile` pixels a side (None: [`SPLAT_TILE`],
    /// or one tile of every particle with `--model-all`): the image is the same whatever the
    /// tile, only its time changes (tested).
    pub fn image_tiled(
        &self,
        gpu: &Gpu,
        net: &Network,
        width: f32,
        medium_step: f32,
        tile: Option<u32>,
    ) -> Result<Splatted, SolverError> {
        let gs = &self.gs;
        let n = self.push.particles;
        let colour = gpu.buffer("networks colours", 16 * n as u64)?;
        let [w, h] = self.size;
        let pixels = gpu.buffer("networks image", 16 * w as u64 * h as u64)?;
        let tiles = SplatTiles::of(&self.view, self.size, net, width, tile, self.force_full);
        let starts = gpu.buffer_with("networks splat tiles", &tiles.starts)?;
        // A one-word stand-in where no tile holds a particle (an empty binding is not allowed).
        let items =
            gpu.buffer_with("networks splat lists", if tiles.items.is_empty() { &[0u32][..] } else { &tiles.items })?;
        let gather = gpu.pipeline(&GATHER, &gs.modelled.spec())?;
        let splat = gpu.pipeline(&SPLAT, &gs.modelled.view_spec())?;
        let (sigma_m, sky) = (self.sigma_m, self.push.sky);
        let passes = [
            gs.bind(Pass::new("networks.gather", QueueRole::Trace, &gather))
                .read(3, &self.positions)
                .read(4, &self.dirs)
                .read(5, &self.direct)
                .read(6, &self.field[self.current])
                .write(7, &colour)
                .read(8, self.emitted())
                .read(9, self.arriving())
                .push(&GatherPush {
                    particles: n,
                    directions: self.push.directions,
                    units: self.push.units,
                    direct: (self.env_dirs == 0) as u32,
                    emission: self.emission.code(),
                })
                .cover([n, 1, 1]),
            gs.bind(Pass::new("networks.splat", QueueRole::Trace, &splat))
                .read(3, &self.positions)
                .read(4, &colour)
                .write(5, &pixels)
                .read(6, &items)
                .read(7, &starts)
                .push(&SplatPush {
                    sigma_m: [sigma_m.x, sigma_m.y, sigma_m.z, 0.0],
                    sky,
                    width: splat_width(net, width),
                    tile: tiles.tile,
                    step: medium_step,
                    tiles_x: tiles.tiles_x,
                })
                .cover([w, h, 1]),
        ];
        let point = gpu.submit(QueueRole::Trace, &passes, &[])?;
        gpu.wait(point)?;
        let px: Vec<[f32; 4]> = gpu.read_buffer_as(&pixels)?;
        if px.iter().any(|p| p[3] < 0.0) {
            return Err(SolverError::Unsupported(
                "networks: a pixel's splats ran past the per-invocation loop guard; use fewer networks.particles"
                    .to_string(),
            ));
        }
        let mut nonfinite = 0u32;
        let data = px
            .iter()
            .flat_map(|p| {
                let ok = p[..3].iter().all(|c| c.is_finite());
                nonfinite += (!ok) as u32;
                if ok {
                    [p[0], p[1], p[2]]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        Ok(Splatted {
            image: crate::output::Image { width: w, height: h, data },
            dropped: px.iter().map(|p| p[3] as u64).sum(),
            nonfinite,
        })
    }
}
